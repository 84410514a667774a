"""Every number the paper states, with units, and the acceptance bands used on them (one place).

Paper = Robust Control of a Parallel-Kinematic Nanopositioner, J. Dyn. Sys.,
Meas., Control 130 (2008), DOI 10.1115/1.2936861. Values are copied from the
paper's text (section named per constant); ``../shared/reference/paper_targets.json``
holds the same figures in machine-readable form.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "PAPER_MODES_HZ", "PAPER_MODE_AXES", "PAPER_GAMMA", "PAPER_CONTROLLER_ORDER", "PAPER_FIT_PERCENT",
    "PAPER_IDENTIFIED_ORDER_PER_COLUMN", "PAPER_REDUCED_ORDER", "PAPER", "BANDS",
]

# --- identified modes (Sec. 3, Fig. 5) ---------------------------------------
PAPER_MODES_HZ = (175.0, 179.0, 245.0, 460.0, 474.0, 740.0)
PAPER_MODE_AXES = ("XY", "XY", "Z", "XY", "XY", "Z")
PAPER_FIT_PERCENT = np.array([[95.9, 95.2, 96.1], [90.2, 91.8, 95.0], [95.1, 89.9, 88.5]])   # Table 1
PAPER_IDENTIFIED_ORDER_PER_COLUMN = 13     # Sec. 3: "the identified model has a rank of 13" per 3x1 column
PAPER_REDUCED_ORDER = 10                   # Sec. 4.1: the first ten balanced states are kept

# --- H-infinity design (Sec. 4.2) --------------------------------------------
PAPER_GAMMA = 1.34
PAPER_CONTROLLER_ORDER = 19

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

# Acceptance bands of the issues (value -> bool), with their text.
BANDS = {
    "mode_rel": (0.03, "within 3 %"),
    "static_gain_rel": (0.05, "<= 0.05"),
    "closure_violation": (0.005, "< 0.5 %"),
    "fit_percent_min": (90.0, ">= 90 %"),
    "gamma_max": (1.5, "<= 1.5"),
    "S_nom_max": (1.5, "<= 1.5"),
    "S_full_max": (1.9, "<= 1.9"),
    "bwS_design_min": (30.0, ">= 30 Hz"),
    "bwT_design_min": (55.0, ">= 55 Hz"),
    "bwS_stage_min": (28.0, ">= 28 Hz"),
    "settle_max_ms": (20.0, "<= 20 ms"),
    "over_max": (15.0, "<= 15 %"),
    "sig_o_band": ((9.12, 13.68), "11.4 +/- 20 %"),
    "sig_c_max": (3.0, "< 3 nm"),
    "hyst_o_band": ((12.0, 18.0), "15 +/- 3 %"),
    "hyst_c_max": (50.0, "< 50 nm (0.25 %)"),
    "creep_open_min": (50.0, "> 50 nm"),
    "creep_closed_max": (5.0, "< 5 nm"),
    "contour_mean_max": (100.0, "< 100 nm"),
    "small_step_tol_nm": (3.0, "within 3 nm"),
}
