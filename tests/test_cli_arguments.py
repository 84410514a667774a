"""The CLI at its edges: file-system errors and bad values give one line naming the argument and exit 2 before
any work, usage errors are one line, ``--version`` and ``python -m nanosim``, the design options, the order
chosen from the singular values, and the weights files without tomllib."""

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nanosim.cli import build_parser, main

from cli_run import ENV, error_lines, in_process, make_sealed_run, nanosim, zero_controller


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    """A complete run made by the CLI (see :func:`cli_run.make_sealed_run`)."""
    return make_sealed_run(tmp_path_factory.mktemp("sealed"))

# --- file-system errors: one line, exit 2, before any work --------------------------------------------
@pytest.fixture
def readonly_dir(tmp_path):
    """A directory nobody can write in, also for root: a read-only tmpfs, else chattr +i, else mode 0555."""
    d = tmp_path / "ro"
    d.mkdir()
    undo = None
    if os.geteuid() != 0:
        d.chmod(0o555)
        undo = ["chmod", "755", str(d)]
    elif subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(d)],
                        capture_output=True).returncode == 0:
        undo = ["umount", str(d)]
    elif shutil.which("chattr") and subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode == 0:
        undo = ["chattr", "-i", str(d)]
    else:
        pytest.skip("running as root without mount or chattr: cannot make a directory read-only")
    assert not os.access(d, os.W_OK)
    yield d
    subprocess.run(undo, capture_output=True)


def test_read_only_out_fails_at_once_with_one_line(readonly_dir):
    t0 = time.monotonic()
    p = nanosim("identify", "--out", readonly_dir / "run")
    elapsed = time.monotonic() - t0
    lines = error_lines(p.stderr)
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert "--out" in lines[0] and ("read-only" in lines[0] or "permission" in lines[0])
    # before any simulation (not a traceback after a simulation); the bound only allows for a loaded machine
    assert "simulating" not in p.stderr and elapsed < 60
    p = nanosim("modes", "--plot", readonly_dir / "plots")
    assert p.returncode == 2 and len(error_lines(p.stderr)) == 1 and "--plot" in p.stderr


def test_out_naming_a_file_and_plot_into_a_file(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    for argv, name in ((("identify", "--out", afile), "--out"), (("modes", "--plot", afile), "--plot"),
                       (("pipeline", "--out", afile), "--out")):
        rc, err = in_process(capsys, *argv)
        assert rc == 2 and len(err) == 1 and name in err[0] and "existing file" in err[0], err


# --- bad values: one line naming the argument, what was expected and what arrived ---------------------
@pytest.fixture
def files(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body></mujoco>")
    rnd = tmp_path / "random.npz"
    rnd.write_bytes(np.random.default_rng(0).bytes(2048))
    return {"tmp": tmp_path, "out": tmp_path / "out", "bad": bad, "rnd": rnd, "dir": tmp_path,
            "ctrl": zero_controller(tmp_path / "c.npz"), "ctrl1ms": zero_controller(tmp_path / "c1ms.npz", dt=1e-3)}


BAD_VALUES = [
    # (argv, words the single line must hold)
    (("design", "--model", "{ctrl}", "--out", "{out}", "--reduced-order", "0"), ["--reduced-order", "got 0"]),
    (("design", "--model", "{ctrl}", "--out", "{out}", "--damping-zeta", "-1"), ["--damping-zeta", "got -1"]),
    (("pipeline", "--out", "{out}", "--reduced-order", "0"), ["--reduced-order", "got 0"]),
    (("modes", "--fmax", "-5"), ["--fmax", "got -5"]),
    (("modes", "--fmax", "nan"), ["--fmax", "got nan"]),
    (("characterize", "--controller", "{ctrl1ms}", "--out", "{out}"), ["dt", "0.00025", "0.001"]),
    (("identify", "--out", "{out}", "--seed", "-1"), ["--seed", "got -1"]),
    (("characterize", "--controller", "{ctrl}", "--out", "{out}", "--seed", "-1"), ["--seed", "got -1"]),
    (("modes", "--mjcf", "{bad}"), ["not a valid MuJoCo model", "line"]),
    (("modes", "--mjcf", "{dir}"), ["--mjcf", "directory"]),
    (("identify", "--out", "{out}", "--mjcf", "{dir}"), ["--mjcf", "directory"]),
    (("design", "--model", "{rnd}", "--out", "{out}"), ["not an .npz file"]),
    (("characterize", "--controller", "{rnd}", "--out", "{out}"), ["not an .npz file"]),
    (("pipeline", "--out", "{out}", "--weights", "{tmp}/none.toml"), ["--weights", "no such file"]),
    (("view", "--seconds", "-5"), ["--seconds", "-5"]),
    (("view", "--seconds", "nan"), ["--seconds", "nan"]),
    (("view", "--host", "999.1.1.1"), ["--host", "999.1.1.1"]),
]


@pytest.mark.parametrize("argv, words", BAD_VALUES, ids=[" ".join(a[:1] + a[-2:]) for a, _ in BAD_VALUES])
def test_bad_values_one_line_exit_2_and_no_folder_left(files, capsys, argv, words):
    argv = [a.format(**files) for a in argv]
    rc, err = in_process(capsys, *argv)
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"nanosim {argv[0]}: error: "), err[0]
    for w in words:
        assert w.lower() in err[0].lower(), (w, err[0])
    assert "allow_pickle" not in err[0] and "busy" not in err[0]
    assert not files["out"].exists()                       # no empty --out left behind


def test_malformed_mjcf_keeps_mujocos_detail_line(files, capsys):
    rc, err = in_process(capsys, "modes", "--mjcf", files["bad"])
    assert rc == 2 and re.search(r"line( number)?\s*[=:]?\s*\d", err[0], re.I), err   # not a bare "XML parse error 8:"


def test_object_array_npz_is_refused_without_pickle_advice(tmp_path, capsys):
    obj = tmp_path / "obj.npz"
    np.savez(obj, a=np.array([{"x": 1}], dtype=object))
    rc, err = in_process(capsys, "design", "--model", obj, "--out", tmp_path / "out")
    assert rc == 2 and "object" in err[0] and "allow_pickle" not in err[0]


def test_view_port_0_picks_a_free_port_and_prints_it():
    p = nanosim("view", "--port", "0", "--seconds", "1", timeout=120)
    assert p.returncode == 0, p.stderr
    port = int(re.search(r"nanosim viewer on http://localhost:(\d+)", p.stdout).group(1))
    assert 0 < port < 65536


def test_pipeline_has_the_design_options():
    args = build_parser().parse_args(["pipeline", "--out", "x", "--weights", __file__, "--reduced-order", "10",
                                      "--damping-zeta", "0", "--paper-design"])
    assert (args.weights, args.reduced_order, args.damping_zeta, args.paper_design) == (__file__, 10, 0.0, True)


def test_order_0_chooses_the_order_from_the_singular_values(monkeypatch, tmp_path, capsys):
    """`identify --order 0` (documented: choose from the singular values) reaches subspace_id as order=None,
    which picks the true order of a 2-mode system (4 states) from noisy data."""
    import identification as ident
    import nanosim.pipeline.identify as pid
    from nanosim.pipeline.config import IdentifyConfig

    assert build_parser().parse_args(["identify", "--out", "x", "--order", "0"]).order == 0
    seen = []

    class Stop(Exception):
        pass

    def fake_identify_stage(settings, model=None, progress=None):
        seen.append(settings.order_per_column)
        raise Stop

    monkeypatch.setattr(pid, "identify_stage", fake_identify_stage)
    with pytest.raises(Stop):
        pid.run_identify(tmp_path, IdentifyConfig(order=0))
    assert seen == [None]
    with pytest.raises(SystemExit):
        main(["identify", "--help"])
    assert "0: choose from the singular values" in " ".join(capsys.readouterr().out.split())
    # a discrete 2-mode system (60 Hz and 300 Hz, zeta 0.02 and 0.05) at 4 kHz, measured with 1 % noise
    fs, rng = 4000.0, np.random.default_rng(1)
    poles = []
    for f, z in ((60.0, 0.02), (300.0, 0.05)):
        w = 2 * np.pi * f
        poles += [np.exp((-z * w + 1j * w * np.sqrt(1 - z * z)) / fs)]
    den = np.real(np.poly(np.concatenate([poles, np.conj(poles)])))
    from scipy.signal import lfilter
    u = rng.standard_normal(8000)
    y = lfilter([0, 0.01, 0.02, 0.01], den, u)
    y += 0.01 * np.std(y) * rng.standard_normal(y.size)
    model = ident.subspace_id(y[:, None], u[:, None], order=None, fs=fs, max_order=12)
    assert model.order == 4


# --- version, python -m, usage errors, weights files --------------------------------------------------
def test_version_and_python_m_nanosim(capsys):
    import nanosim

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"nanosim {nanosim.__version__}"
    p = subprocess.run([sys.executable, "-m", "nanosim", "--help"], capture_output=True, text=True, env=ENV)
    assert p.returncode == 0
    for cmd in ("modes", "identify", "design", "characterize", "pipeline", "report", "view"):
        assert cmd in p.stdout


def test_characterize_bar_names_the_running_experiment(sealed):
    assert "running small_steps" in sealed[2].stderr


def test_usage_errors_are_one_line(capsys):
    rc, err = in_process(capsys, "identify")
    assert rc == 2 and len(err) == 1 and "--out" in err[0] and "usage:" not in err[0]


def test_weights_parse_toml_without_tomllib(tmp_path):
    """Python 3.10 has no tomllib: weights.py falls back on tomli (pyproject: tomli for python < 3.11)."""
    toml = tmp_path / "w.toml"
    toml.write_text("[Wp]\nnum = [0.6667, 314.2]\nden = [1, 0.03142]\n[Wt]\nnum = [1, 314.2]\n"
                    "den = [0.001, 628.3]\npower = 2\n[Wu]\nnum = [0.15]\nden = [1]\n")
    code = ("import sys, types, tomllib\n"
            "t = types.ModuleType('tomli'); t.loads = tomllib.loads; t.TOMLDecodeError = tomllib.TOMLDecodeError\n"
            "sys.modules['tomli'] = t; sys.modules['tomllib'] = None   # import tomllib now fails as on 3.10\n"
            "from nanosim.design.weights import Weights\n"
            f"w = Weights.from_file({str(toml)!r}); print(w.Wt.power, w.Wu.num)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV)
    assert p.returncode == 0 and p.stdout.split()[0] == "2", p.stderr
    pyproject = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert re.search(r'"tomli[^"]*;\s*python_version\s*<\s*.3\.11.', pyproject)
    assert 'requires-python = ">=3.10"' in pyproject
