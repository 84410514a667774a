"""Closed-loop characterization on the stage, as in the paper's Section 5.

Each experiment is a function of a *stage factory* (a fresh :class:`Stage`,
or a :class:`TwinStage` with the same electromechanics around the linear
twin) and the discrete controller, and returns a frozen result. The loop is
``e_k = r_k - y_k`` (sensor volts), ``u_k = K e_k`` (controller volts),
``y_{k+1} = stage.step(u_k)``. References are in um from the probe origin;
closed-loop runs first ramp from the home reading to the origin and settle.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import signal

import identification as ident

from nanosim import constants as C
from nanosim.ramps import raised_cosine
from nanosim.design.controller import DiscreteController
from nanosim.design.legacy import _crossing as crossing_hz
from nanosim.plant.electronics import ActuatorChain, SensorChain
from nanosim.plant.piezo import loop_hysteresis_percent
from nanosim.plant.stage import StageConfig, Trace

FS = C.CONTROL_RATE_HZ
UM_PER_V = C.SENSOR_UM_PER_V


class TwinStage:
    """The linear twin wrapped in the same electromechanics as :class:`Stage`.

    Same ``step``/``run``/``reset`` API: DAC, amplifier, piezo hysteresis and
    creep, gauge noise and ADC act exactly as on the MuJoCo stage; only the
    mechanics is the 4 kHz discrete linear twin.
    """

    def __init__(self, twin, seed: int = 0, config: StageConfig | None = None, home_um=None, home_qpos=None):
        self.config = config or StageConfig()
        self.seed = seed
        sysd = twin.sysd_V
        self._A, self._B, self._C, self._D = sysd.A, sysd.B, sysd.C, sysd.D
        self._qC, self._qD = getattr(twin, "qpos_C", None), getattr(twin, "qpos_D", None)
        self._q0 = None if home_qpos is None else np.asarray(home_qpos, float).copy()
        self._home_um = np.zeros(3) if home_um is None else np.asarray(home_um, float)
        self.dt_s = twin.dt_s
        self.reset()

    def reset(self) -> None:
        self.actuators = ActuatorChain(self.config.electronics, self.config.piezo, seed=self.seed)
        self.sensors = SensorChain(self.config.electronics, seed=self.seed)
        self._x = np.zeros(self._A.shape[0])
        self._v = np.zeros(3)
        self.time_s = 0.0
        self.table_um = self._home_um.copy()
        self.last_saturated = np.zeros(3, dtype=bool)
        self.last_piezo_V = np.zeros(3)

    def step(self, u_V) -> np.ndarray:
        act = self.actuators.step(u_V)
        v_eq = act.v_free_V / self.config.electronics.amplifier_gain      # equivalent controller volts
        self._v = v_eq
        self._x = self._A @ self._x + self._B @ v_eq
        self.table_um = self._home_um + UM_PER_V * (self._C @ self._x + self._D @ v_eq)
        self.time_s += self.dt_s
        self.last_saturated = act.saturated
        self.last_piezo_V = act.v_piezo_V
        return self.sensors.step(self.table_um).reading_V

    @property
    def qpos(self) -> np.ndarray:
        """Joint positions of the linearized mechanism (needs a twin built ``with_qpos`` and ``home_qpos``)."""
        if self._qC is None or self._q0 is None:
            raise ValueError("qpos: build the twin with linearize(..., with_qpos=True) and pass home_qpos")
        return self._q0 + self._qC @ self._x + self._qD @ self._v

    def run(self, u_V) -> Trace:
        """Open-loop run with the same record layout as :meth:`Stage.run`."""
        u = np.asarray(u_V, float)
        rows = []
        for uk in u:
            y = self.step(uk)
            rows.append((self.last_piezo_V, self.last_saturated, self.table_um.copy(), y))
        pz, sat, tb, ys = (np.array(c) for c in zip(*rows))
        return Trace(t_s=self.dt_s * np.arange(1, len(u) + 1), u_V=u, piezo_V=pz, saturated=sat, table_um=tb,
                     sensor_V=ys, sensor_um=ys * UM_PER_V, clipped=np.zeros_like(sat))


@dataclass(frozen=True)
class LoopTrace:
    """Closed-loop record at 4 kHz (um, V, s)."""

    t_s: np.ndarray
    ref_um: np.ndarray
    y_um: np.ndarray
    table_um: np.ndarray
    u_V: np.ndarray
    saturated: np.ndarray

    @property
    def error_um(self) -> np.ndarray:
        return self.ref_um - self.y_um


def run_closed_loop(stage, controller: DiscreteController, ref_um: np.ndarray, *, settle: bool = True,
                    settle_s: float = 0.6) -> LoopTrace:
    """Run the loop on ``ref_um`` (N, 3); with ``settle`` first move to ref_um[0] from home."""
    ref_um = np.asarray(ref_um, float)
    y = stage.sensors.step(stage.table_um).reading_V if hasattr(stage, "sensors") else np.zeros(3)
    if settle:
        if controller.two_dof:      # damping-loop states at equilibrium with the home reading
            controller.reset(measurement_V=y)
        n = int(settle_s * FS)
        start = y * UM_PER_V
        w = raised_cosine(n, 0.6)
        pre = start + w[:, None] * (ref_um[0] - start)
        for r in pre:
            y = stage.step(controller.feedback(r / UM_PER_V, y))
    n = len(ref_um)
    ys, tb, us, sat = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3), bool)
    for k in range(n):
        u = controller.feedback(ref_um[k] / UM_PER_V, y)
        ys[k] = y * UM_PER_V
        tb[k] = stage.table_um
        us[k] = u
        y = stage.step(u)
        sat[k] = stage.last_saturated
    return LoopTrace(t_s=np.arange(n) / FS, ref_um=ref_um, y_um=ys, table_um=tb, u_V=us, saturated=sat)


StageFactory = Callable[[int], object]


def _plateaus(y, dwell: int, count: int):
    """Mean and std of the settled second half of ``count`` consecutive dwells of ``dwell`` samples."""
    parts = [y[i * dwell + dwell // 2:(i + 1) * dwell] for i in range(count)]
    return np.array([p.mean() for p in parts]), np.array([p.std() for p in parts])


# -- 1. hysteresis ---------------------------------------------------------------
@dataclass(frozen=True)
class HysteresisResult:
    """Open loop: actuator A 0 -> 1.65 -> 0 V. Closed loop: X 0 -> 20 um -> 0.

    ``closed_loop_nm`` is the largest gap between the settled positions on the
    way up and on the way down (a staircase of ``levels`` levels), the
    hysteresis that remains under feedback; ``closed_ramp_lag_nm`` is the
    branch gap of the continuous triangle, dominated by velocity lag.
    """

    open_v: np.ndarray
    open_y_um: np.ndarray
    open_loop_percent: float
    open_loop_input_percent: float
    open_travel_um: np.ndarray
    closed: LoopTrace
    closed_levels_um: np.ndarray
    closed_up_um: np.ndarray
    closed_down_um: np.ndarray
    closed_loop_nm: float
    closed_loop_percent: float
    closed_ramp_lag_nm: float


def _branch_gap(x, y, n_grid=400) -> float:
    """Max vertical gap between rising and falling branches of y(x) on a triangle x."""
    k = int(np.argmax(x))
    grid = np.linspace(max(x[:k + 1].min(), x[k:].min()), x[k], n_grid)[1:-1]
    up = np.interp(grid, x[:k + 1], y[:k + 1])
    dn = np.interp(grid, x[k:][::-1], y[k:][::-1])
    return float(np.abs(up - dn).max())


def hysteresis(factory: StageFactory, controller, seed=0, duration_s=2.0, travel_um=20.0, levels=11,
               dwell_s=0.12) -> HysteresisResult:
    n = int(duration_s * FS)
    tri = np.concatenate([np.linspace(0, 1, n // 2), np.linspace(1, 0, n - n // 2)])
    u = np.zeros((n, 3))
    u[:, 0] = 1.65 * tri
    tr = factory(seed).run(u)
    y = tr.sensor_um - tr.sensor_um[0]
    travel = y[n // 2 - 1]
    out_pct, in_pct = loop_hysteresis_percent(u[:, 0], np.sign(travel[0]) * y[:, 0])
    ref = np.zeros((n, 3))
    ref[:, 0] = travel_um * tri
    controller.reset()
    cl = run_closed_loop(factory(seed + 1), controller, ref)
    lag_nm = _branch_gap(ref[:, 0], cl.y_um[:, 0]) * 1e3
    lv = np.linspace(0, travel_um, levels)
    seq = np.concatenate([lv, lv[-2::-1]])
    nd = int(dwell_s * FS)
    sref = np.zeros((len(seq) * nd, 3))
    sref[:, 0] = np.repeat(seq, nd)
    controller.reset()
    st = run_closed_loop(factory(seed + 2), controller, sref)
    settled, _ = _plateaus(st.y_um[:, 0], nd, len(seq))
    up, down = settled[:levels], settled[levels - 1:][::-1]
    gap_nm = float(np.abs(up - down).max() * 1e3)
    return HysteresisResult(open_v=u[:, 0], open_y_um=y, open_loop_percent=out_pct, open_loop_input_percent=in_pct,
                            open_travel_um=travel, closed=cl, closed_levels_um=lv, closed_up_um=up,
                            closed_down_um=down, closed_loop_nm=gap_nm,
                            closed_loop_percent=100 * gap_nm * 1e-3 / travel_um, closed_ramp_lag_nm=lag_nm)


# -- 2. creep ----------------------------------------------------------------------
@dataclass(frozen=True)
class CreepResult:
    t_s: np.ndarray
    open_y_um: np.ndarray
    closed_y_um: np.ndarray
    open_drift_nm: np.ndarray      # per axis, over the hold
    closed_drift_nm: np.ndarray
    hold_s: float


def _drift_nm(y, n_after):
    w = int(0.2 * FS)
    return (y[-w:].mean(0) - y[n_after:n_after + w].mean(0)) * 1e3


def creep(factory: StageFactory, controller, G0_um_per_V, seed=0, hold_s=10.0) -> CreepResult:
    """Move to the origin and hold: open loop through inv(G0), and closed loop."""
    n_move, n_hold = int(0.1 * FS), int(hold_s * FS)
    st = factory(seed)
    home = st.sensors.step(st.table_um).reading_um if hasattr(st, "sensors") else np.zeros(3)
    v0 = np.linalg.solve(G0_um_per_V, -home)
    w = raised_cosine(n_move)
    u = np.vstack([w[:, None] * v0, np.tile(v0, (n_hold, 1))])
    tr = st.run(u)
    y_open = tr.sensor_um[n_move:]
    cl = run_closed_loop(factory(seed + 1), controller, np.zeros((n_hold, 3)), settle_s=0.1)
    n_after = int(0.5 * FS)
    return CreepResult(t_s=np.arange(n_hold) / FS, open_y_um=y_open, closed_y_um=cl.y_um,
                       open_drift_nm=_drift_nm(y_open, n_after), closed_drift_nm=_drift_nm(cl.y_um, n_after),
                       hold_s=hold_s)


# -- 3. resolution -----------------------------------------------------------------
@dataclass(frozen=True)
class ResolutionResult:
    open_y_nm: np.ndarray
    closed_y_nm: np.ndarray
    sigma_nm: dict
    band2_nm: dict
    band3_nm: dict
    psd_freq_hz: np.ndarray
    psd_open: np.ndarray
    psd_closed: np.ndarray


def _bands(x_nm):
    dev = np.abs(x_nm - x_nm.mean())
    return float(x_nm.std()), float(np.percentile(dev, 95.45)), float(np.percentile(dev, 99.73))


def resolution(factory: StageFactory, controller, seed=0, duration_s=4.0, axis=0) -> ResolutionResult:
    n = int(duration_s * FS)
    st = factory(seed)
    st.run(np.zeros((int(0.3 * FS), 3)))
    y_open = st.run(np.zeros((n, 3))).sensor_um[:, axis] * 1e3
    cl = run_closed_loop(factory(seed + 1), controller, np.zeros((n, 3)))
    y_closed = cl.y_um[:, axis] * 1e3
    so, so2, so3 = _bands(y_open)
    sc, sc2, sc3 = _bands(y_closed)
    f, po = signal.welch(y_open - y_open.mean(), fs=FS, nperseg=2048)
    _, pc = signal.welch(y_closed - y_closed.mean(), fs=FS, nperseg=2048)
    return ResolutionResult(open_y_nm=y_open, closed_y_nm=y_closed,
                            sigma_nm={"open_loop": so, "closed_loop": sc},
                            band2_nm={"open_loop": so2, "closed_loop": sc2},
                            band3_nm={"open_loop": so3, "closed_loop": sc3},
                            psd_freq_hz=f, psd_open=po, psd_closed=pc)


# -- 4. 10 nm steps ------------------------------------------------------------------
@dataclass(frozen=True)
class SmallStepsResult:
    trace: LoopTrace
    targets_nm: np.ndarray
    plateau_mean_nm: np.ndarray
    plateau_sigma_nm: np.ndarray


def small_steps(factory: StageFactory, controller, seed=0, step_nm=10.0, n_steps=5, dwell_s=0.15,
                axis=0) -> SmallStepsResult:
    nd = int(dwell_s * FS)
    targets = step_nm * np.arange(n_steps + 1)
    ref = np.zeros(((n_steps + 1) * nd, 3))
    ref[:, axis] = np.repeat(targets, nd) * 1e-3
    cl = run_closed_loop(factory(seed), controller, ref)
    means, sig = _plateaus(cl.y_um[:, axis] * 1e3, nd, n_steps + 1)
    means = means - means[0]
    return SmallStepsResult(trace=cl, targets_nm=targets, plateau_mean_nm=means, plateau_sigma_nm=sig)


# -- 5. bandwidth and step -----------------------------------------------------------
@dataclass(frozen=True)
class BandwidthResult:
    freq_hz: np.ndarray
    sigma_S: np.ndarray
    sigma_T: np.ndarray
    bandwidth_S_hz: float
    bandwidth_T_hz: float
    step: LoopTrace
    rise_ms: float
    peak_ms: float
    settling_ms: float
    overshoot_percent: float


def step_metrics(t_s, y, final):
    y = y / final
    rise = t_s[np.argmax(y >= 0.9)] - t_s[np.argmax(y >= 0.1)]
    ipk = int(np.argmax(y))
    outside = np.flatnonzero(np.abs(y - 1) > 0.02)
    if not len(outside):
        settle = t_s[0]
    elif outside[-1] + 1 < len(t_s):
        settle = t_s[outside[-1] + 1]
    else:
        settle = float("inf")                     # not settled inside the record
    return 1e3 * rise, 1e3 * t_s[ipk], 1e3 * settle, 100 * max(0.0, y[ipk] - 1)


def bandwidth(factory: StageFactory, controller, seed=0, duration_s=4.0, amplitude_um=2.0,
              step_um=2.0) -> BandwidthResult:
    """sigma(S), sigma(T) from three uncorrelated PRBS references (MIMO H1), and a 2 um step.

    The PRBS amplitude (2 um) drives the piezos with about the same swing as the
    identification experiment: the hysteretic actuator's gain depends on amplitude.
    """
    n = int(duration_s * FS)
    ref = np.stack([ident.prbs(n, 800.0, fs=FS, amplitude=amplitude_um, seed=seed * 10 + i) for i in range(3)], 1)
    cl = run_closed_loop(factory(seed), controller, ref)
    est_T = ident.h1_estimate(ref, cl.y_um, fs=FS, nperseg=2048)
    f = est_T.freq_hz
    band = (f >= 1.0) & (f <= 1000.0)
    T = np.moveaxis(est_T.H[:, :, band], -1, 0)
    S = np.eye(3)[None] - T
    sT = np.linalg.svd(T, compute_uv=False)[:, 0]
    sS = np.linalg.svd(S, compute_uv=False)[:, 0]
    fb = f[band]
    lvl = 1 / np.sqrt(2)
    bS = crossing_hz(fb, sS, lvl, rising=True)
    bT = crossing_hz(fb, sT, lvl, rising=False)
    ns = int(0.3 * FS)
    sref = np.zeros((ns + int(0.01 * FS), 3))
    sref[int(0.01 * FS):, 0] = step_um
    stp = run_closed_loop(factory(seed + 1), controller, sref)
    k0 = int(0.01 * FS)
    t = stp.t_s[k0:] - stp.t_s[k0]
    y = stp.y_um[k0:, 0] - stp.y_um[:k0, 0].mean()
    rise, peak, settle, over = step_metrics(t, y, step_um)
    return BandwidthResult(freq_hz=fb, sigma_S=sS, sigma_T=sT, bandwidth_S_hz=bS, bandwidth_T_hz=bT, step=stp,
                           rise_ms=rise, peak_ms=peak, settling_ms=settle, overshoot_percent=over)


# -- 6. tracking ------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackingCase:
    waveform: str
    freq_hz: float
    trace: LoopTrace
    rms_error_nm: float
    max_error_nm: float
    phase_lag_deg: float


def _wave(kind, f, t, amp):
    ph = 2 * np.pi * f * t
    if kind == "sine":
        return amp * 0.5 * (1 - np.cos(ph))
    return amp * np.abs(signal.sawtooth(ph, 0.5) + 1) / 2


def tracking(factory: StageFactory, controller, seed=0, freqs_hz=(5, 10, 20, 40), amplitude_um=10.0,
             periods=3, axis=0) -> list:
    cases = []
    for kind in ("triangle", "sine"):
        for f in freqs_hz:
            n = int((periods + 1) / f * FS)
            t = np.arange(n) / FS
            ref = np.zeros((n, 3))
            ref[:, axis] = _wave(kind, f, t, amplitude_um)
            controller.reset()
            cl = run_closed_loop(factory(seed), controller, interpolate(ref))
            keep = slice(int(1 / f * FS), n)
            e = cl.error_um[keep, axis] * 1e3
            tt = t[keep]
            basis = np.exp(-2j * np.pi * f * tt)
            lag = np.angle(np.sum(cl.ref_um[keep, axis] * basis) / np.sum(cl.y_um[keep, axis] * basis))
            cases.append(TrackingCase(kind, float(f), cl, float(np.sqrt(np.mean(e ** 2))), float(np.abs(e).max()),
                                      float(np.degrees(lag))))
    return cases


# -- 7. contouring ------------------------------------------------------------------------
@dataclass(frozen=True)
class ContourCase:
    speed_um_s: float
    trace: LoopTrace
    contour_error_nm: np.ndarray
    mean_error_nm: float
    max_error_nm: float
    axis_tracking_error_um: float


INTERPOLATION_S = 0.0025


def interpolate(ref_um, smoothing_s: float = INTERPOLATION_S, fs: float = FS) -> np.ndarray:
    """The motion controller's command interpolation: two moving averages of ``smoothing_s``.

    The paper's UMAC interpolates commands (Sec. 5: "the command signals ... get
    round off at the corner"); two boxcars give an S-curve with finite
    acceleration and jerk. Straight paths stay on their line.
    """
    n = max(1, int(round(smoothing_s * fs)))
    if n == 1:
        return np.asarray(ref_um, float)
    k = np.ones(n) / n
    pad = np.pad(np.asarray(ref_um, float), ((2 * n, 2 * n), (0, 0)), mode="edge")
    out = np.apply_along_axis(lambda c: np.convolve(np.convolve(c, k, "same"), k, "same"), 0, pad)
    return out[2 * n:-2 * n]


def contour_reference(speed_um_s, corner_um=20.0, fs=FS, dwell_s=0.02, smoothing_s=INTERPOLATION_S):
    """45 degree line (0,0) -> (c,c) -> (0,0) at constant speed along the path (um), interpolated."""
    length = np.hypot(corner_um, corner_um)
    n = max(2, int(round(length / speed_um_s * fs)))
    s = np.linspace(0, 1, n)
    dwell = np.ones(int(dwell_s * fs))
    leg = np.concatenate([np.zeros(int(dwell_s * fs)), s, dwell, s[::-1]]) * corner_um
    ref = np.zeros((len(leg) + int(dwell_s * fs), 3))
    ref[:len(leg), 0] = leg
    ref[:len(leg), 1] = leg
    return interpolate(ref, smoothing_s, fs)


def contouring(factory: StageFactory, controller, seed=0, speeds_um_s=(10, 30, 100, 300, 1000)) -> list:
    cases = []
    for v in speeds_um_s:
        ref = contour_reference(v)
        controller.reset()
        cl = run_closed_loop(factory(seed), controller, ref)
        x, y = cl.y_um[:, 0], cl.y_um[:, 1]
        moving = (ref[:, 0] > 0.5) & (ref[:, 0] < 19.5)
        d = np.abs(x - y)[moving] / np.sqrt(2) * 1e3          # distance to the 45 degree path
        ax_err = np.abs(cl.error_um[moving, :2]).max()
        cases.append(ContourCase(float(v), cl, d, float(d.mean()), float(d.max()), float(ax_err)))
    return cases


EXPERIMENTS = ("hysteresis", "creep", "resolution", "small_steps", "bandwidth", "tracking", "contouring")
