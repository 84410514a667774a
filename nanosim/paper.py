"""Every number the paper states, with units, and the acceptance bands used on them (one place).

Paper = Robust Control of a Parallel-Kinematic Nanopositioner, J. Dyn. Sys.,
Meas., Control 130 (2008), DOI 10.1115/1.2936861. Values are copied from the
paper's text (section named per constant); ``../shared/reference/paper_targets.json``
holds the same figures in machine-readable form.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "PAPER_MODES_HZ", "PAPER_MODE_AXES", "PAPER_GAMMA", "PAPER_CONTROLLER_ORDER", "PAPER_FIT_PERCENT",
    "PAPER_IDENTIFIED_ORDER_PER_COLUMN", "PAPER_REDUCED_ORDER", "PAPER_APPENDIX_A_DAMPING",
    "PAPER_MODE_DAMPING_MEAN", "PAPER_REDUCTION_ERROR_MAX_DB_BELOW_140HZ", "PAPER", "PAPER_FULL_STROKE_UM",
    "PAPER_OPEN_LOOP_TRAVEL_UM", "PAPER_HYSTERESIS_INPUT_PERCENT", "PAPER_CREEP_POLE_RAD_S",
    "PAPER_CREEP_ZERO_OVER_POLE", "PAPER_PRBS_BANDS_HZ", "PAPER_STEP_UM", "PAPER_CONTOUR_SPEED_UM_S",
    "PAPER_SAMPLE_RATE_HZ", "tustin_warp_hz", "tustin_unwarp_hz", "tustin_unwarp_damping", "STAGE_MODES_HZ",
    "STAGE_MODE_DAMPING_MEAN",
    "Band", "BANDS", "MODE_REL_TOL",
    "STATIC_GAIN_REL_TOL", "CLOSURE_VIOLATION_MAX", "SMALL_STEP_TOL_NM",
]

# --- the stage (Sec. 2) ---------------------------------------------------------
PAPER_FULL_STROKE_UM = 87.0      # "a maximum displacement of about 87 um along each axis"

# --- open loop (Sec. 3-4, Fig. 14; Appendix A) --------------------------------
PAPER_OPEN_LOOP_TRAVEL_UM = (-10.0, 7.1, 5.4)   # X, Y, Z travel for actuator A 0 -> 1.65 V (Fig. 14)
PAPER_HYSTERESIS_INPUT_PERCENT = 14.0          # open-loop input hysteresis (%), Fig. 14
# the identified real pole / zero pair (creep doublet) of each column, Appendix A: poles from ... to (rad/s),
# zero / pole ratios from ... to (-)
PAPER_CREEP_POLE_RAD_S = (28.97, 33.11)
PAPER_CREEP_ZERO_OVER_POLE = (1.08, 1.11)

# --- sampling (Sec. 3): the loop and the identification run at 4 kHz ----------------------------
PAPER_SAMPLE_RATE_HZ = 4000.0

# --- identification (Sec. 3, Fig. 4a): a step, then PRBS in three bands of 1 s each, at most 0.5 V ----------
PAPER_PRBS_BANDS_HZ = (50.0, 100.0, 200.0)
PAPER_PRBS_AMPLITUDE_V = 0.5         # the excitation's largest command [controller V]

# --- identified modes (Sec. 3, Fig. 5) ---------------------------------------
PAPER_MODES_HZ = (175.0, 179.0, 245.0, 460.0, 474.0, 740.0)
PAPER_MODE_AXES = ("XY", "XY", "Z", "XY", "XY", "Z")
PAPER_FIT_PERCENT = np.array([[95.9, 95.2, 96.1], [90.2, 91.8, 95.0], [95.1, 89.9, 88.5]])   # Table 1
PAPER_IDENTIFIED_ORDER_PER_COLUMN = 13     # Sec. 3: "the identified model has a rank of 13" per 3x1 column
PAPER_REDUCED_ORDER = 10                   # Sec. 4.1: the first ten balanced states are kept
# Appendix A: damping ratio b / (2 sqrt(c)) of the six second-order denominator factors of each column
# (actuator A, B, C), modes in PAPER_MODES_HZ order (../shared/reference/paper_targets.json,
# key appendix_A_denominators)
PAPER_APPENDIX_A_DAMPING = {
    "A": (0.00314, 0.00383, 0.00342, 0.00387, 0.00356, 0.00749),
    "B": (0.00297, 0.00372, 0.00330, 0.00497, 0.00558, 0.00316),
    "C": (0.00295, 0.00352, 0.00377, 0.00767, 0.00366, 0.00341),
}
PAPER_MODE_DAMPING_MEAN = tuple(float(np.mean(col)) for col in zip(*PAPER_APPENDIX_A_DAMPING.values()))



def tustin_warp_hz(f_hz, fs_hz: float = PAPER_SAMPLE_RATE_HZ):
    """Continuous frequency that Tustin's d2c (no prewarp) gives a discrete mode of true frequency ``f_hz``.

    A continuous mode at ``f_hz`` sampled exactly has its pole at angle theta = 2 pi f / fs; the
    bilinear map s = (2 fs) (z - 1) / (z + 1) puts that angle at f_w = (fs / pi) tan(pi f / fs)
    (Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed., Sec. 6.3.2).
    """
    f = np.asarray(f_hz, float)
    if np.any(f < 0) or np.any(f >= fs_hz / 2):
        raise ValueError(f"f_hz: expected 0 <= f < fs/2 = {fs_hz / 2} Hz, got {f_hz!r}")
    return fs_hz / np.pi * np.tan(np.pi * f / fs_hz)


def tustin_unwarp_hz(f_hz, fs_hz: float = PAPER_SAMPLE_RATE_HZ):
    """True frequency of a mode that Tustin's d2c (no prewarp) reported at ``f_hz``: inverse of
    :func:`tustin_warp_hz`, f = (fs / pi) atan(pi f_w / fs).
    """
    f = np.asarray(f_hz, float)
    if np.any(f < 0):
        raise ValueError(f"f_hz: expected frequencies >= 0, got {f_hz!r}")
    return fs_hz / np.pi * np.arctan(np.pi * f / fs_hz)


def tustin_unwarp_damping(zeta, f_hz, fs_hz: float = PAPER_SAMPLE_RATE_HZ):
    """True damping ratio of a lightly damped mode that Tustin's d2c reported as ``zeta`` at ``f_hz``.

    To first order in zeta, s = 2 fs tanh(s_true / (2 fs)) scales the decay rate by 1 / cos^2(theta)
    and the frequency by tan(theta) / theta (theta = pi f_true / fs), so the reported damping is
    zeta_w = zeta_true 2 theta / sin(2 theta).
    """
    theta = np.pi * tustin_unwarp_hz(f_hz, fs_hz) / fs_hz
    return np.asarray(zeta, float) * np.sin(2 * theta) / (2 * theta)


# The stage the paper's procedure implies: its Tustin-converted modes and damping, unwarped (the MJCF's
# calibration targets; the identification with the paper's d2c returns PAPER_MODES_HZ from it).
STAGE_MODES_HZ = tuple(float(f) for f in tustin_unwarp_hz(PAPER_MODES_HZ))
STAGE_MODE_DAMPING_MEAN = tuple(float(z) for z in tustin_unwarp_damping(PAPER_MODE_DAMPING_MEAN, PAPER_MODES_HZ))

# --- H-infinity design (Sec. 4.2) --------------------------------------------
PAPER_GAMMA = 1.34
PAPER_CONTROLLER_ORDER = 19
# Sec. 4.1: the model-reduction uncertainty is "lower than -20 dB below 140 Hz" (Fig. 10)
PAPER_REDUCTION_ERROR_MAX_DB_BELOW_140HZ = -20.0

# --- the closed-loop experiments (Sec. 5) -----------------------------------------
PAPER_STEP_UM = 2.0                  # the step of Fig. 18c (the "step_2um" metrics)
PAPER_SETTLING_BAND = 0.02           # the step's settling band, a fraction of the step (Fig. 18c)
PAPER_CONTOUR_SPEED_UM_S = 1000.0    # the contour speed of the errors quoted for Fig. 20

# Figures quoted in Secs. 4-5 (units in the comment). Keys are used by the report.
PAPER = {
    "modes": PAPER_MODES_HZ, "gamma": PAPER_GAMMA, "order": PAPER_CONTROLLER_ORDER,
    "S_nom": 1.45,           # peak sigma(S), nominal model (-)
    "S_full": 1.85,          # peak sigma(S), full model (-)
    "bwS": 32.0,             # S bandwidth (Hz), Fig. 18a
    "bwT": 59.0,             # T bandwidth (Hz), Fig. 18b
    "rise": 5.0, "peak": 8.0, "settle": 11.0,   # 2 um step (ms), Fig. 18c
    "over": 8.0,             # overshoot (%)
    "sig_o": 11.4, "sig_c": 1.89,               # resolution sigma open/closed loop (nm), Fig. 16
    "s2_o": 22.6, "s2_c": 4.8, "s3_o": 30.1, "s3_c": 6.9,   # 95.45 % / 99.73 % bands (nm)
    "hyst_o": 15.0,          # open-loop output hysteresis (% of travel), Fig. 14a
    "hyst_c": 20.0,          # closed-loop hysteresis (nm), Fig. 14b
    "contour_mean": 40.0, "contour_max": 70.0,  # contour error at 1000 um/s (nm), Fig. 20
    "axis_err": 3.0,         # per-axis tracking error at 1000 um/s (um), Fig. 20b
}

@dataclass(frozen=True)
class Band:
    """An acceptance band: ``low <= value <= high`` (``<``/``>`` when ``strict``), with its text."""

    low: float | None = None
    high: float | None = None
    strict: bool = False
    text: str = ""

    def ok(self, value) -> bool:
        """True if ``value`` lies inside the band."""
        v = float(value)
        if self.low is not None and (v <= self.low if self.strict else v < self.low):
            return False
        return not (self.high is not None and (v >= self.high if self.strict else v > self.high))


# Acceptance bands on the paper's quantities (the report's "ok" column), each with its text.
BANDS = {
    "fit_percent": Band(low=90.0, text=">= 90 %"),
    "gamma": Band(high=1.5, text="<= 1.5"),
    "S_peak_nominal": Band(high=1.5, text="<= 1.5"),
    "S_peak_full": Band(high=1.9, text="<= 1.9"),
    "bandwidth_S_design_hz": Band(low=30.0, text=">= 30 Hz"),
    "bandwidth_T_design_hz": Band(low=55.0, text=">= 55 Hz"),
    "bandwidth_S_stage_hz": Band(low=28.0, text=">= 28 Hz"),
    "settling_ms": Band(high=20.0, text="<= 20 ms"),
    "overshoot_percent": Band(high=15.0, text="<= 15 %"),
    "sigma_open_nm": Band(low=0.8 * 11.4, high=1.2 * 11.4, text="11.4 +/- 20 %"),
    "sigma_closed_nm": Band(high=3.0, strict=True, text="< 3 nm"),
    "hysteresis_open_percent": Band(low=12.0, high=18.0, text="15 +/- 3 %"),
    "hysteresis_closed_nm": Band(high=50.0, strict=True, text="< 50 nm (0.25 %)"),
    "creep_open_nm": Band(low=50.0, strict=True, text="> 50 nm"),
    "creep_closed_nm": Band(high=5.0, strict=True, text="< 5 nm"),
    "contour_mean_nm": Band(high=100.0, strict=True, text="< 100 nm"),
    "mode_damping": Band(low=0.002, high=0.01, text="0.002-0.01"),      # lightly damped flexure modes
    "controller_order": Band(low=PAPER_CONTROLLER_ORDER, high=PAPER_CONTROLLER_ORDER,
                             text=f"= {PAPER_CONTROLLER_ORDER} (paper)"),
}
MODE_REL_TOL = 0.03              # modes within 3 %
STATIC_GAIN_REL_TOL = 0.05       # static gain vs 3.0 um/V x J, max error / max element
CLOSURE_VIOLATION_MAX = 0.005    # loop-closure violation at full stroke
SMALL_STEP_TOL_NM = 3.0          # 10 nm staircase plateaus within 3 nm
