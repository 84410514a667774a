"""Run the stage calibration (nanosim.plant.calibrate.CALIBRATION_PARAMS) from several starts.

The asymmetric fit has local minima (which chain is stiffer than which), so it starts from the
symmetric design with the chains' webs pushed apart in each sign pattern of a few, and keeps the
lowest cost. It prints the fitted values, the modes, the residuals and the active bounds: put the
values into ``nanosim.plant.geometry._calibrated`` and regenerate the bundled MJCF
(``nanosim.plant.build.write_bundled``).

Usage: ``python tools/calibrate_stage.py`` (about a minute).
"""
from __future__ import annotations

import itertools

import numpy as np

from nanosim.plant.calibrate import CALIBRATION_PARAMS, EDM_TOLERANCE_M, fit, get_param, set_param
from nanosim.plant.geometry import CHAINS, DEFAULT_GEOMETRY, HINGE_FAMILIES

# chain web offsets of a start, in units of half the tolerance: every pattern of a stiffer and a softer
# chain (the third at the design web), applied to all four families alike or to fb2/swing opposite
PATTERNS = [dict(zip(CHAINS, p)) for p in itertools.permutations((1.0, -1.0, 0.0))]
# the prior on each calibrated deviation (calibrate.fit): its bound is the process's 2-sigma tolerance
PRIOR = 2.0


def start(pattern: dict, flip_legs: bool):
    """The design geometry with each chain's webs offset by the pattern (all families or legs flipped)."""
    g = DEFAULT_GEOMETRY
    for ch in CHAINS:
        for fam in HINGE_FAMILIES:
            sign = -1.0 if (flip_legs and fam in ("fb2", "swing")) else 1.0
            path = f"notch.{ch}_{fam}"
            g = set_param(g, path, get_param(g, path) + sign * pattern[ch] * 0.5 * EDM_TOLERANCE_M)
    return g


def main() -> int:
    """Fit from every start and print the best."""
    results = []
    for pattern, flip in itertools.product(PATTERNS, (False, True)):
        r = fit(CALIBRATION_PARAMS, start(pattern, flip), max_nfev=300, prior=PRIOR)
        results.append(r)
        print(f"start {pattern} flip_legs={flip}: cost {r.cost:.3f}")
    best = min(results, key=lambda r: r.cost)
    s = best.summary
    ixy, iz = s.observed()
    print("\nbest cost", round(best.cost, 4))
    for p in CALIBRATION_PARAMS:
        print(f"  {p.path:28s} {best.values[p.path] * 1e6:10.3f} um   in [{p.lo * 1e6:.3f}, {p.hi * 1e6:.3f}]")
    print("XY modes", np.round(s.freq_hz[ixy], 2), "Z modes", np.round(s.freq_hz[iz], 2))
    print("all modes < 7.5 kHz", np.round(s.freq_hz[s.freq_hz < 7500], 1))
    print("gain um/V\n", np.round(s.gain_um_per_V, 3))
    print("residuals", np.round(best.residuals, 2))
    print("active bounds", best.active_bounds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
