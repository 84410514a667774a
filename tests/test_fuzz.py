"""Property-based fuzzing of the public API and the CLI's argument parsing (hypothesis, derandomized).

Contract: on any input, a public entry point returns a well-formed result or raises one of the
documented exceptions (``ValueError`` -- its subclasses included --, ``FileNotFoundError``; argparse's
``SystemExit`` with status 0 or 2). Anything else escaping is a bug. ``tests/corpus/`` holds malformed
files (truncated/garbage/object-array npz, MJCF variants); ``tests/corpus/make_corpus.py`` rebuilds it.
The whole file runs in well under 2 minutes (fixed example counts, ``derandomize=True``).
"""
from __future__ import annotations

import contextlib
import io
import json
import warnings
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, currently_in_test_context, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

CORPUS = Path(__file__).resolve().parent / "corpus"
DOCUMENTED = (ValueError, FileNotFoundError)
FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def fuzz(n):
    return settings(FUZZ, max_examples=n)


# --- generic "anything array-like" -------------------------------------------------------------------
finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
any_float = st.floats(allow_nan=True, allow_infinity=True)
dtypes = st.sampled_from([np.float64, np.float32, np.int64, np.int8, np.bool_, np.complex128, np.uint8])
weird_arrays = st.one_of(
    hnp.arrays(dtype=dtypes, shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4)),
    hnp.arrays(dtype=np.float64, shape=st.sampled_from([(3,), (1, 3), (2, 3), (0, 3), (3, 1)]), elements=any_float),
)
junk = st.one_of(st.none(), st.booleans(), st.text(max_size=4), any_float, st.integers(),
                 st.lists(any_float, max_size=5), st.lists(st.text(max_size=2), max_size=3),
                 st.dictionaries(st.text(max_size=3), st.integers(), max_size=2), weird_arrays)


@contextlib.contextmanager
def documented_only():
    """Let only the documented exceptions through (numpy/MuJoCo warnings are not failures)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            yield
        except DOCUMENTED as exc:
            if currently_in_test_context():
                event(f"raised {type(exc).__name__}")   # see --hypothesis-show-statistics


# --- Stage ---------------------------------------------------------------------------------------------
@lru_cache(maxsize=1)
def _model():
    from nanosim.plant.mjcf import load_model
    return load_model()


def _stage(seed=0):
    from nanosim.plant.stage import Stage
    return Stage(seed=seed, model=_model())


@fuzz(60)
@given(u=st.one_of(junk, hnp.arrays(np.float64, (3,), elements=st.floats(-1e300, 1e300))))
def test_stage_step_returns_finite_volts_or_value_error(u):
    stage = _stage()
    with documented_only():
        y = stage.step(u)
        assert y.shape == (3,) and np.all(np.isfinite(y))
        assert np.all(np.isfinite(stage.table_um))


@fuzz(40)
@given(u=st.one_of(junk, hnp.arrays(np.float64, st.tuples(st.integers(0, 12), st.just(3)),
                                     elements=st.floats(-1e300, 1e300))))
def test_stage_run_returns_a_trace_or_value_error(u):
    stage = _stage()
    with documented_only():
        tr = stage.run(u)
        n = np.shape(u)[0]
        assert tr.sensor_V.shape == (n, 3) and np.all(np.isfinite(tr.sensor_V))
        assert tr.t_s.shape == (n,)


# --- controller runtime --------------------------------------------------------------------------------
def _mat(rows, cols, elements=finite):
    return hnp.arrays(np.float64, (rows, cols), elements=elements)


@st.composite
def controllers(draw):
    n = draw(st.integers(0, 4))
    ne = draw(st.integers(1, 3))
    nin = ne * draw(st.sampled_from([1, 2]))
    nout = draw(st.integers(1, 3))
    scale = draw(st.sampled_from([1.0, 0.5, 1e-3]))       # 1.0: possibly unstable, still finite over a few steps
    return draw(corrupt({"Akd": draw(_mat(n, n, st.floats(-1, 1))) * scale, "Bkd": draw(_mat(n, nin)),
                         "Ckd": draw(_mat(nout, n)), "Dkd": draw(_mat(nout, nin)), "dt": 2.5e-4,
                         "n_error": draw(st.sampled_from([None, ne]))}))


def _signal(n):
    return st.one_of(hnp.arrays(np.float64, (n,), elements=finite), junk)


@fuzz(150)
@given(kw=controllers(), data=st.data(), steps=st.integers(0, 5))
def test_discrete_controller_construct_step_reset(kw, data, steps):
    from nanosim.design.controller import DiscreteController

    k = None
    with documented_only():                 # only the call under fuzz may raise the documented errors
        k = DiscreteController.from_matrices(**kw)
    if k is None:
        return
    event("constructed")
    ne, nm, nx = k.config.n_error, k.config.n_measurement, k.config.n_states
    with documented_only():
        k.reset(data.draw(_signal(nx)))
    with documented_only():
        k.reset(measurement_V=data.draw(_signal(nm)))
    for _ in range(steps):
        with documented_only():
            out = k.step(data.draw(_signal(ne)), data.draw(_signal(nm)) if nm else None)
            assert out.shape == (k.config.n_out,) and np.all(np.isfinite(out))
    with documented_only():
        out = k.feedback(data.draw(_signal(ne)), data.draw(_signal(ne)))
        assert out.shape == (k.config.n_out,)
    # valid path on a constructed controller: no exception of any kind is allowed here
    good_e = np.linspace(-1, 1, ne)
    k.reset()
    out = k.step(good_e, np.zeros(nm) if nm else None)
    assert out.shape == (k.config.n_out,) and np.all(np.isfinite(out))
    seq = k.run(np.tile(good_e, (4, 1)), measurement_seq=np.zeros((4, nm)) if nm else None)
    assert seq.shape == (4, k.config.n_out)
    event("ran")


# --- identification ------------------------------------------------------------------------------------
@st.composite
def corrupt(draw, valid: dict):
    """``valid`` keyword arguments with, two times in three, one of them replaced by junk or an edge value."""
    args = dict(valid)
    key = draw(st.sampled_from([*sorted(args), None, None]))   # ~1/3 of the time all arguments stay valid
    if key is not None:
        args[key] = draw(st.one_of(junk, st.sampled_from([0, -1, 0.0, -0.0, 1e-310, 5e-324, 1e308, 2**63, -2**63,
                                                          float("nan"), float("inf"), True, np.float32(1.5),
                                                          np.int64(7)])))
    return args


@st.composite
def prbs_args(draw):
    fs = draw(st.sampled_from([4000.0, 1000.0, 1.0, 1e-3, 1e9]))
    return draw(corrupt({"n_samples": draw(st.integers(1, 5000)), "band_hz": draw(st.floats(1e-300, fs / 2)),
                         "fs": fs, "amplitude": draw(st.floats(1e-12, 1e12)),
                         "seed": draw(st.one_of(st.integers(0, 2**64), st.just(np.random.default_rng(1))))}))


@fuzz(150)
@given(kw=prbs_args())
def test_prbs(kw):
    import identification as ident

    with documented_only():
        u = ident.prbs(**kw)
        event("ok")
        assert u.shape == (int(kw["n_samples"]),)
        assert set(np.unique(np.abs(u))) <= {float(kw["amplitude"])}


@st.composite
def fit_args(draw):
    shape = draw(st.sampled_from([(1,), (2,), (50,), (50, 1), (50, 3), (0,), (0, 2)]))
    y = draw(hnp.arrays(np.float64, shape, elements=st.floats(-1e6, 1e6)))
    yhat = y + draw(hnp.arrays(np.float64, shape, elements=st.floats(-1e3, 1e3)))
    return draw(corrupt({"y": y, "yhat": yhat}))


@fuzz(100)
@given(kw=fit_args())
def test_fit_percent(kw):
    import identification as ident

    with documented_only():
        f = np.asarray(ident.fit_percent(kw["y"], kw["yhat"]))
        event("ok")
        assert np.all(f <= 100.0 + 1e-9)


@st.composite
def subspace_args(draw):
    n = draw(st.integers(5, 300))
    ny, nu = draw(st.integers(1, 2)), draw(st.integers(1, 2))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    u = rng.standard_normal((n, nu)) * draw(st.sampled_from([1.0, 1e-6, 1e6]))
    a = draw(st.floats(-0.99, 0.99))
    x = np.zeros(ny)
    y = np.empty((n, ny))
    for k in range(n):                                       # a first-order system per output, plus noise
        y[k] = x
        x = a * x + u[k].sum()
    y += draw(st.sampled_from([0.0, 1e-3, 1.0])) * rng.standard_normal((n, ny))
    return draw(corrupt({"y": y, "u": u, "order": draw(st.one_of(st.none(), st.integers(1, 6))),
                         "horizon": draw(st.one_of(st.none(), st.integers(2, 15))), "fs": 4000.0,
                         "max_order": draw(st.integers(1, 8)), "enforce_stability": draw(st.booleans()),
                         "feedthrough": draw(st.booleans())}))


@fuzz(80)
@given(kw=subspace_args())
def test_subspace_id_on_tiny_data(kw):
    import identification as ident

    m = None
    with documented_only():                 # only the call under fuzz may raise the documented errors
        m = ident.subspace_id(**kw)
    if m is None:
        return
    event("ok")
    # a model subspace_id returned must simulate and convert: no exception of any kind is allowed here
    assert m.A.shape == (m.order, m.order) and np.all(np.isfinite(m.A))
    yhat = ident.simulate(m, kw["u"], m.x0)
    assert yhat.shape == np.shape(kw["y"])
    cont = ident.d2c(m)
    assert cont.nstates == m.order


@st.composite
def d2c_args(draw):
    import control as ct

    n = draw(st.integers(0, 4))
    poles = draw(st.lists(st.one_of(st.floats(-0.999, 0.999), st.sampled_from([-1.0, 1.0, 0.0, -0.999999999])),
                          min_size=n, max_size=n))
    q = np.linalg.qr(np.random.default_rng(n).standard_normal((n, n)))[0] if n else np.zeros((0, 0))
    A = q @ np.diag(poles) @ q.T if n else np.zeros((0, 0))
    dt = draw(st.one_of(st.just(2.5e-4), st.just(2.5e-4), st.sampled_from([1.0, 1e-9, True, None, 0])))
    sysd = ct.ss(A, np.ones((n, 1)), np.ones((1, n)), np.zeros((1, 1)), dt)
    return draw(corrupt({"sys": sysd, "method": draw(st.sampled_from(["tustin", "zoh"])),
                         "prewarp_hz": draw(st.one_of(st.none(), st.floats(1e-3, 1999.0)))}))


@fuzz(100)
@given(kw=d2c_args())
def test_d2c(kw):
    import identification as ident

    with documented_only():
        sysc = ident.d2c(kw.pop("sys"), **kw)
        event("ok")
        assert np.all(np.isfinite(sysc.A))


# --- weights parsing ------------------------------------------------------------------------------------
good_coeffs = st.lists(st.floats(0.01, 1e3), min_size=1, max_size=3)


@st.composite
def weight_value(draw):
    """A valid weight (number or {num, den, power}) with, half the time, one field replaced by junk."""
    if draw(st.booleans()):
        return draw(st.one_of(st.floats(0.01, 10), junk))
    spec = {"num": draw(good_coeffs), "den": draw(good_coeffs), "power": draw(st.integers(1, 3))}
    field = draw(st.sampled_from(["num", "den", "power", "zeros", None]))
    if field is not None:
        spec[field] = draw(st.one_of(st.sampled_from([None, [], [0.0, 0.0], [1.0], "2", {}, 2.5, -1, True]), junk))
    if draw(st.integers(0, 5)) == 0:
        del spec[draw(st.sampled_from(["num", "den", "power"]))]
    return spec


@st.composite
def weight_dicts(draw):
    data = {k: draw(weight_value()) for k in ("Wp", "Wt", "Wu")}
    mutation = draw(st.sampled_from(["none", "drop", "rename", "absent", "nest", "junk"]))
    if mutation == "drop":
        del data[draw(st.sampled_from(sorted(data)))]
    elif mutation == "rename":
        data["wp"] = data.pop("Wp")
    elif mutation == "absent":
        data[draw(st.sampled_from(sorted(data)))] = draw(st.sampled_from([None, False, "none", " NONE "]))
    elif mutation == "nest":
        data = {"hinf": data, "gamma": 1.34}
    elif mutation == "junk":
        return draw(junk)
    return data


@fuzz(150)
@given(data=weight_dicts())
def test_weights_from_dict(data):
    from nanosim.design.weights import Weights

    w = None
    with documented_only():                 # only the call under fuzz may raise the documented errors
        w = Weights.from_dict(data)
    if w is None:
        return
    assert Weights.from_dict(w.to_dict()) == w               # round trip of accepted weights: must not raise
    with documented_only():
        w.check()


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) and np.isfinite(v) else ("nan" if v != v else
                                                                               ("inf" if v > 0 else "-inf"))
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(str(v))


@fuzz(80)
@given(data=weight_dicts(), fmt=st.sampled_from(["json", "toml", "toml-raw", "json-raw", "txt"]),
       raw=st.text(max_size=60))
def test_weights_from_file(tmp_path_factory, data, fmt, raw):
    from nanosim.design.weights import Weights

    d = tmp_path_factory.mktemp("w")
    if fmt == "json":
        text = json.dumps(data, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    elif fmt == "toml" and isinstance(data, dict):
        lines = []
        for k, v in data.items():
            if isinstance(v, dict):
                lines.append(f"[{json.dumps(str(k))}]")
                lines += [f"{json.dumps(str(kk))} = {_toml_value(vv if not hasattr(vv, 'tolist') else vv.tolist())}"
                          for kk, vv in v.items()]
            else:
                lines.insert(0, f"{json.dumps(str(k))} = {_toml_value(v if not hasattr(v, 'tolist') else v.tolist())}")
        text = "\n".join(lines)
    else:
        text = raw
    path = d / f"w.{fmt.split('-')[0]}"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    with documented_only():
        w = Weights.from_file(path)
        assert set(w.to_dict()) == {"Wp", "Wt", "Wu"}


# --- npz and MJCF loaders on the corpus and on generated bytes -------------------------------------------
NPZ_CORPUS = sorted((CORPUS / "npz").glob("*.npz"))
MJCF_CORPUS = sorted((CORPUS / "mjcf").glob("*.xml"))


def test_corpus_is_present():
    assert len(NPZ_CORPUS) >= 15 and len(MJCF_CORPUS) >= 10


@pytest.mark.parametrize("path", NPZ_CORPUS, ids=[p.name for p in NPZ_CORPUS])
def test_npz_corpus_gives_one_line_value_errors(path, tmp_path, capsys):
    from nanosim.cli import main
    from nanosim.design.controller import DiscreteController
    from nanosim.design.lti import load_state_space_npz
    from nanosim.fileio import load_npz

    for load in (load_npz, lambda p: DiscreteController.from_npz(p, expected_dt=2.5e-4), load_state_space_npz):
        with documented_only():
            load(path)
    with pytest.raises(ValueError, match=str(path.name)):                # no corpus file is a valid controller
        DiscreteController.from_npz(path, expected_dt=2.5e-4)
    assert main(["characterize", "--controller", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nanosim characterize: error:") and "allow_pickle" not in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("path", MJCF_CORPUS, ids=[p.name for p in MJCF_CORPUS])
def test_mjcf_corpus_gives_one_line_value_errors(path):
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.stage import Stage

    with pytest.raises(ValueError) as exc:
        Stage(mjcf=path)                           # no corpus file is a usable stage
    msg = str(exc.value)
    assert "\n" not in msg.strip() and ("mjcf" in msg or path.name in msg), msg
    with documented_only():
        load_model(path)


@fuzz(60)
@given(data=st.one_of(st.binary(max_size=600),
                      st.sampled_from(NPZ_CORPUS).map(lambda p: p.read_bytes()).flatmap(
                          lambda b: st.tuples(st.integers(0, len(b)), st.binary(max_size=8)).map(
                              lambda t: b[:t[0]] + t[1] + b[t[0] + len(t[1]):]))))
def test_load_npz_on_generated_bytes(tmp_path_factory, data):
    from nanosim.fileio import load_npz

    p = tmp_path_factory.mktemp("npz") / "x.npz"
    p.write_bytes(data)
    with documented_only():
        arrays = load_npz(p)
        assert all(a.dtype != object for a in arrays.values())


@fuzz(40)
@given(cut=st.integers(0, 14000), insert=st.sampled_from(["", "<", ">", "&", "<body>", "\"", "nan", "-1e400", "\x00"]))
def test_load_model_on_mangled_stage_xml(tmp_path_factory, cut, insert):
    from nanosim.plant.mjcf import DEFAULT_MJCF, load_model

    text = (DEFAULT_MJCF.parent / "pkxyz_stage.xml").read_text()
    cut = min(cut, len(text))
    p = tmp_path_factory.mktemp("mjcf") / "stage.xml"
    p.write_text(text[:cut] + insert + text[cut + len(insert):])
    with documented_only():
        load_model(p)


# --- the CLI's argument parsing -----------------------------------------------------------------------
OPTIONS = ["--out", "--seed", "--order", "--ideal", "--mjcf", "--model", "--weights", "--reduced-order",
           "--damping-zeta", "--paper-design", "--controller", "--only", "--twin", "--json", "--plot", "--fmax",
           "--run", "--port", "--host", "--physics", "--seconds", "--version", "-h", "--help", "--nope"]
COMMANDS = ["modes", "identify", "design", "characterize", "pipeline", "report", "view", "nope", ""]
VALUES = ["0", "-1", "13", "1e9", "nan", "inf", "-inf", "0.5", "", " ", "x", "--", "-", "/nonexistent",
          "tests", "pyproject.toml", "1" * 30, "\u00e9", "0x10", "1_000"]


@fuzz(300)
@given(argv=st.lists(st.one_of(st.sampled_from(COMMANDS), st.sampled_from(OPTIONS), st.sampled_from(VALUES),
                               st.text(max_size=6)), max_size=8))
def test_parse_args_only_namespace_or_exit_0_2(argv):
    from nanosim.cli import build_parser

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            ns = build_parser().parse_args(argv)
        except SystemExit as exc:
            assert exc.code in (0, 2), (argv, exc.code)
            if exc.code == 2:
                lines = err.getvalue().strip().splitlines()
                assert len(lines) == 1 and lines[0].startswith("nanosim"), (argv, err.getvalue())
            return
    assert ns.command in COMMANDS and callable(ns.func)
    for name in ("seed", "order", "reduced_order"):
        v = getattr(ns, name, 0)
        assert isinstance(v, int) and v >= 0
    for name in ("damping_zeta", "fmax"):
        v = getattr(ns, name, 0.5)
        assert np.isfinite(v)
