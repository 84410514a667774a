"""Identify the stage from data, as the paper does (Sec. 3).

One experiment per actuator (step + PRBS in the paper's 50/100/200 Hz bands
and, beyond the paper, a 1 kHz band for the sixth mode (paper: 740 Hz); at most 0.5
controller volts, 4 kHz), a 3x1 discrete model per column by subspace
identification, the 3x3 model assembled block-diagonally (39 states for
13 per column), continuous time by the inverse Tustin transform. Fit factors
are computed on a separate validation record (another PRBS seed).

Beyond the paper (``IdentifySettings.shared_poles``, default on): a resonance
belongs to the structure, so the lightly damped poles that several columns
share are re-estimated jointly from all three records, one pole per mode
(:func:`identification.refine_shared_poles`), so a column that barely excites a
mode does not set its frequency and damping alone: its estimate, from a record
with little energy near the mode, is biased high in both.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import control as ct
import numpy as np

import identification as ident
from nanosim import constants as C
from nanosim.design.lti import single_threaded_blas
from nanosim.paper import PAPER_IDENTIFIED_ORDER_PER_COLUMN, PAPER_PRBS_AMPLITUDE_V
from nanosim.plant.noise import stream_seed
from nanosim.plant.stage import StageConfig, Trace, run_open_loop_batch
from nanosim.ramps import raised_cosine

__all__ = ["IdentifySettings", "IdentifiedStage", "run_experiments", "assemble", "identify_stage", "twin_runner",
           "identify_on_twin", "merge_close_modes", "merged_modes",
           "unshared_resonances_hz", "without_resonances", "SHARED_MODE_TOL", "LIGHT_DAMPING"]

AXES, ACTS = C.AXES, C.ACTUATORS


@dataclass(frozen=True)
class IdentifySettings:
    """Experiment and model settings (units in names)."""

    seed: int = 0
    order_per_column: int | None = PAPER_IDENTIFIED_ORDER_PER_COLUMN
    amplitude_V: float = PAPER_PRBS_AMPLITUDE_V
    offset_piezo_V: float = 0.0          # operating point (paper: 0 V and 80 V)
    settle_s: float = 1.5                # ramp to the operating point and settle
    ideal: bool = False                  # every electromechanical effect off
    shared_poles: bool = True            # one pole per mode, from every column's record (not the paper)
    bands_hz: tuple = C.DEFAULT_PRBS_BANDS_HZ   # PRBS band edges, 1 s each (paper: 50, 100, 200 Hz)

    @property
    def offset_V(self) -> float:
        """Operating point in controller volts (piezo volts / amplifier gain)."""
        return self.offset_piezo_V / C.AMPLIFIER_GAIN


@dataclass(frozen=True)
class IdentifiedStage:
    """3x3 model from controller volts to sensor volts, with its evidence."""

    sysd: ct.StateSpace                   # discrete, dt = 250 us
    sysc: ct.StateSpace                   # continuous (inverse Tustin)
    columns: tuple                        # IdentifiedModel per actuator
    fit_percent: np.ndarray               # (3, 3) rows XYZ, cols ABC, validation data
    settings: IdentifySettings
    estimation: tuple                     # (u (N,), y (N, 3)) per column, deviations
    validation: tuple
    modes: list = field(default_factory=list)
    shared: ident.SharedPoles | None = None    # the joint re-estimation of the shared resonances


def _experiment_inputs(settings: IdentifySettings, seed_offset: int):
    ex = ident.paper_excitation(fs=C.CONTROL_RATE_HZ, amplitude=settings.amplitude_V, bands_hz=settings.bands_hz,
                                seed=stream_seed(settings.seed, "identification.excitation", seed_offset))
    n_settle = int(settings.settle_s * C.CONTROL_RATE_HZ)
    ramp = settings.offset_V * raised_cosine(n_settle, 0.5)
    cmds = np.zeros((3, n_settle + len(ex.u), 3))
    for j in range(3):
        cmds[j, :n_settle, :] = ramp[:, None]
        cmds[j, n_settle:, :] = settings.offset_V
        cmds[j, n_settle:, j] += ex.u
    return ex, cmds, n_settle


def run_experiments(settings: IdentifySettings, model=None, config: StageConfig | None = None, runner=None):
    """Simulate the estimation and validation experiments (6 runs in parallel).

    ``config`` overrides the stage's electromechanics (default: every effect
    on, or none with ``settings.ideal``); ``runner`` replaces
    :func:`~nanosim.plant.stage.run_open_loop_batch` (same call:
    ``runner(u_batch, seeds=..., config=..., model=...)``), e.g. to identify
    the linear twin.
    """
    ex_e, cmd_e, n0 = _experiment_inputs(settings, 1)
    ex_v, cmd_v, _ = _experiment_inputs(settings, 2)
    cfg = config if config is not None else (StageConfig.ideal() if settings.ideal else StageConfig())
    seeds = [stream_seed(settings.seed, "identification", k) for k in range(6)]
    traces = (runner or run_open_loop_batch)(np.concatenate([cmd_e, cmd_v]), seeds=seeds, config=cfg, model=model)
    return ex_e, ex_v, traces[:3], traces[3:], n0


def _deviation(trace: Trace, n0: int, j: int, offset_V: float):
    """Input and output deviations from the operating point (record after settling).

    Pairs each command with the reading the controller had when it computed
    it, as the bench's data gathering does: command ``u_k`` (computed at
    ``t_k``) with the reading taken at ``t_k``, i.e. the trace's reading of
    row ``k - 1``. (A trace row holds the reading at the *end* of its period;
    pairing that with ``u_k`` would give the model one sample less delay than
    the loop it is designed for.)
    """
    y = trace.sensor_V[n0 - 1:-1]
    baseline = trace.sensor_V[n0 - int(0.1 * C.CONTROL_RATE_HZ):n0].mean(axis=0)
    return trace.u_V[n0:, j] - offset_V, y - baseline


def assemble(columns) -> ct.StateSpace:
    """Block-diagonal 3x3 discrete model from three 3x1 column models."""
    n = [c.order for c in columns]
    A = np.zeros((sum(n), sum(n)))
    B = np.zeros((sum(n), 3))
    Cm = np.hstack([c.C for c in columns])
    D = np.hstack([c.D for c in columns])
    k = 0
    for j, c in enumerate(columns):
        A[k:k + n[j], k:k + n[j]] = c.A
        B[k:k + n[j], j] = c.B[:, 0]
        k += n[j]
    return ct.ss(A, B, Cm, D, columns[0].dt_s)


def identify_stage(settings: IdentifySettings = IdentifySettings(), model=None, progress=None,
                   config: StageConfig | None = None, runner=None) -> IdentifiedStage:
    """Run the experiments on the simulated stage and identify the 3x3 model.

    ``config`` and ``runner``: see :func:`run_experiments`.
    """
    ex_e, ex_v, tr_e, tr_v, n0 = run_experiments(settings, model, config, runner)
    if progress:
        progress("experiments simulated")
    with single_threaded_blas():        # same bits on any core count (tall QR and least squares)
        return _identify(settings, n0, tr_e, tr_v)


def twin_runner(twin, model):
    """A record runner (the call of :func:`~nanosim.plant.stage.run_open_loop_batch`) on a linear twin.

    Each record runs on a :class:`~nanosim.plant.batch.BatchTwinStage` of ``twin`` in the electromechanics of
    the record's ``config`` (DAC, amplifier, piezo, sensors, noise), from the table's home position of ``model``
    and with its floor model, so the twin's records differ from MuJoCo's only by the mechanics' linearization.

    Parameters
    ----------
    twin : nanosim.plant.linearize.LinearTwin
        The linearized mechanics.
    model : mujoco.MjModel
        The stage the twin linearizes (its home position and floor model).

    Returns
    -------
    callable
        ``runner(u_batch, *, seeds, config=None, model=None)``, for :func:`identify_stage`'s ``runner``.
    """
    from nanosim.plant.batch import BatchTwinStage
    from nanosim.plant.floor import floor_model
    from nanosim.plant.stage import Stage

    home_um, floor = Stage(model=model).table_um.copy(), floor_model(model)

    def runner(u_batch, *, seeds, config=None, model=None):
        return BatchTwinStage(twin, seeds, config=config, home_um=home_um, floor_models=floor).run(u_batch)

    return runner


def identify_on_twin(model=None, settings: IdentifySettings = IdentifySettings(), progress=None) -> tuple:
    """Identify the stage on its linear twin: the experiments of :func:`identify_stage`, mechanics linearized.

    The ideal stage of ``model`` (:meth:`~nanosim.plant.stage.StageConfig.ideal`, every electromechanical
    effect off) is linearized by MuJoCo (:func:`~nanosim.plant.linearize.linearize`); the identification
    experiments then run on that twin in the full electromechanics (:func:`twin_runner`), a fraction of
    MuJoCo's cost, and the records are identified as :func:`identify_stage` identifies MuJoCo's.

    Parameters
    ----------
    model : mujoco.MjModel, optional
        The stage (default: the bundled MJCF).
    settings : IdentifySettings
        Seed, bands and orders of the identification.
    progress : callable, optional
        Called with one status line when the experiments are simulated.

    Returns
    -------
    IdentifiedStage, nanosim.plant.linearize.LinearTwin
        The identified model and the twin it was identified on.
    """
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.runplant import RunPlant

    model = load_model() if model is None else model
    twin = RunPlant.of_model(model).twin
    return identify_stage(settings, model=model, progress=progress, runner=twin_runner(twin, model)), twin


def _identify(settings: IdentifySettings, n0: int, tr_e, tr_v) -> IdentifiedStage:
    """The models of :func:`identify_stage` from its records."""
    est = [_deviation(tr_e[j], n0, j, settings.offset_V) for j in range(3)]
    val = [_deviation(tr_v[j], n0, j, settings.offset_V) for j in range(3)]

    def identify(j, order):
        u_e, y_e = est[j]
        return ident.subspace_id(y_e, u_e[:, None], order=order, fs=C.CONTROL_RATE_HZ, max_order=20,
                                 enforce_stability=True, input_names=(ACTS[j],), output_names=AXES)

    columns = [identify(j, settings.order_per_column) for j in range(3)]
    # a resonance one column alone has is an artefact of that column's spare states: drop it
    columns = [without_resonances(col, hz, *est[j]) if hz else col
               for j, (col, hz) in enumerate(zip(columns, unshared_resonances_hz(columns)))]
    shared = ident.refine_shared_poles(columns, est) if settings.shared_poles else None
    if shared is not None:
        columns = list(shared.columns)
    # a real pole slower than the record is not resolved by it: its gain extrapolates past the data
    columns = [without_slow_poles(col, len(est[j][0]) / C.CONTROL_RATE_HZ, *est[j]) for j, col in enumerate(columns)]
    fit = np.zeros((3, 3))
    for j, col in enumerate(columns):
        u_v, y_v = val[j]
        x0 = ident.estimate_x0(col, y_v, u_v[:, None])
        fit[:, j] = ident.fit_percent(y_v, ident.simulate(col, u_v[:, None], x0))
    sysd = assemble(columns)
    sysc = ident.d2c(sysd, method="tustin")
    modes = []
    for j, col in enumerate(columns):
        m = ident.modes_from_model(col.A, col.dt_s)
        modes.append({"column": ACTS[j], "freq_hz": list(map(float, m.freq_hz)),
                      "damping_ratio": list(map(float, m.damping))})
    return IdentifiedStage(sysd=sysd, sysc=sysc, columns=tuple(columns), fit_percent=fit, settings=settings,
                           estimation=tuple(est), validation=tuple(val), modes=modes, shared=shared)


# A resonance of the structure is lightly damped, and every actuator that drives it shows it; an
# actuator on a nodal line of a mode (actuator A of the v1 stage, for the 176.3 and 464.5 Hz modes)
# leaves it to the other columns. A lightly damped pair that no other column has within the modal
# frequency uncertainty (3 %) is therefore not a mode of the stage but the column's spare states
# (paper order 13 for a column with fewer modes) fitting noise, creep and hysteresis, such as a
# low-frequency pole-zero pair that only one column has. Weakly excited true modes, estimated a little differently
# in each column, stay.
SHARED_MODE_TOL = 0.03
LIGHT_DAMPING = ident.LIGHT_DAMPING          # the same "resonance" as the shared-pole refinement's


def unshared_resonances_hz(columns, tol: float = SHARED_MODE_TOL, zeta_max: float = LIGHT_DAMPING) -> list:
    """Per column, the lightly damped resonances [Hz] that no other column has.

    Parameters
    ----------
    columns : sequence of identification.IdentifiedModel
        The 3x1 column models.
    tol : float
        Relative frequency within which two columns' poles are the same mode.
    zeta_max : float
        Damping ratio below which a complex pole pair is a resonance.

    Returns
    -------
    list of list of float
        One list per column (empty when every resonance is shared).
    """
    modes = [ident.modes_from_model(c.A, c.dt_s) for c in columns]
    out = []
    for j, m in enumerate(modes):
        others = np.concatenate([modes[k].freq_hz for k in range(len(modes)) if k != j] or [np.zeros(0)])
        out.append([float(f) for f, z in zip(m.freq_hz, m.damping)
                    if z < zeta_max and not np.any(np.abs(others - f) <= tol * f)])
    return out


def without_slow_poles(col, tau_max_s: float, u, y):
    """``col`` without its real poles slower than ``tau_max_s`` (modal truncation), ``x0, B, D`` refitted.

    A record of ``T`` seconds resolves a first-order process only if its time constant is shorter
    than ``T``: a slower real pole (``tau = -dt / ln z > T``) fits drift, creep or the record's end, and
    its gain, which sets the model's DC gain, extrapolates beyond the data. ``col`` itself when it has none.

    Parameters
    ----------
    col : identification.IdentifiedModel
        A 3x1 column model.
    tau_max_s : float
        Longest time constant kept [s] (the record's length).
    u, y : ndarray
        The column's estimation record, as :func:`without_resonances`.
    """
    dt = col.dt_s
    z = np.linalg.eigvals(np.asarray(col.A, float))
    slow = [p for p in z if abs(p.imag) < 1e-12 and 0 < p.real < 1 and -dt / np.log(p.real) > tau_max_s]
    if not slow:
        return col

    return _modal_truncation(col, lambda re, im: not (abs(im) < 1e-12 and 0 < re < 1
                                                      and -dt / np.log(re) > tau_max_s), u, y)


def without_resonances(col, freqs_hz, u, y):
    """``col`` without the resonances at ``freqs_hz`` (modal truncation), ``x0, B, D`` refitted.

    Parameters
    ----------
    col : identification.IdentifiedModel
        A 3x1 column model.
    freqs_hz : sequence of float
        Resonances to remove, as :func:`identification.modes_from_model` reports them [Hz].
    u : ndarray, shape (N,)
        The column's estimation input [controller V].
    y : ndarray, shape (N, 3)
        Its output [sensor V].

    Returns
    -------
    identification.IdentifiedModel
        Two states less per resonance; the other poles exactly those of ``col``.
    """
    def keep(re, im):
        z = complex(re, im)
        if z == 0:
            return True
        s = np.log(z) / col.dt_s
        return not any(abs(abs(s) / (2 * np.pi) - f) <= 1e-9 * f for f in freqs_hz)

    return _modal_truncation(col, keep, u, y)


def _modal_truncation(col, keep, u, y):
    """``col`` reduced to the eigenvalues ``keep(re, im)`` accepts (ordered real Schur form, block-diagonalized),
    ``x0, B, D`` refitted on the record ``u, y``; the kept poles are exactly those of ``col``.
    """
    import dataclasses

    import scipy.linalg as sla

    from identification.regression import fit_x0_B_D
    T, Z, k = sla.schur(np.asarray(col.A, float), output="real", sort=keep)
    X = sla.solve_sylvester(T[:k, :k], -T[k:, k:], -T[:k, k:])          # block-diagonalizes T
    Kt = Z.T @ np.asarray(col.K, float)
    A1, C1, K1 = T[:k, :k], (np.asarray(col.C, float) @ Z)[:, :k], Kt[:k] - X @ Kt[k:]
    x0, B1, D1 = fit_x0_B_D(A1, C1, np.asarray(u, float).reshape(len(u), -1), np.asarray(y, float), True)
    return dataclasses.replace(col, A=A1, B=B1, C=C1, D=D1, K=K1, x0=x0, order=int(k))


def merge_close_modes(pairs, tol: float = 0.004) -> list[dict]:
    """Merge ``(frequency Hz, damping ratio)`` pairs that are the same mode seen more than once.

    The pairs are sorted by frequency; a pair within ``tol`` relative frequency of the previous one joins its
    group (a chain, so a group may span more than ``tol`` end to end). Each group is one mode at the median
    frequency and damping ratio of its pairs, with ``seen_in_columns`` the number of pairs.
    """
    merged: list[tuple[list, list]] = []
    for f, z in sorted((float(f), float(z)) for f, z in pairs):
        if merged and abs(f - merged[-1][0][-1]) <= tol * f:
            merged[-1][0].append(f)
            merged[-1][1].append(z)
        else:
            merged.append(([f], [z]))
    return [{"freq_hz": float(np.median(fs)), "damping_ratio": float(np.median(zs)), "seen_in_columns": len(fs)}
            for fs, zs in merged]


def merged_modes(result: IdentifiedStage, tol: float = 0.004):
    """Modes above 20 Hz seen in the columns, merged when within ``tol`` (:func:`merge_close_modes`)."""
    return merge_close_modes(((f, z) for m in result.modes for f, z in zip(m["freq_hz"], m["damping_ratio"])
                              if f > 20), tol)
