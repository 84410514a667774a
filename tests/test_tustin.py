"""Tustin consistency: the paper's warped modes, the stage they imply, and controllers brought back exactly.

The paper converts its 4 kHz discrete model by Tustin without prewarping (Sec. 3), so its continuous modes
are f_w = (fs / pi) tan(pi f / fs) of the stage's f. The MJCF is calibrated to f (``paper.STAGE_MODES_HZ``);
its exact discretization, converted as the paper did, must give back the paper's numbers; and a controller
designed on such a Tustin-converted model must be discretized by Tustin so that its notches sit on the
plant's discrete poles.
"""
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

import identification as ident
from nanosim import paper as P

ct = pytest.importorskip("control")

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"
FS = P.PAPER_SAMPLE_RATE_HZ


def lightly_damped_hz(A, dt=None, f_max_hz=1000.0, zeta_max=0.05):
    m = ident.modes_from_model(np.asarray(A, float), dt)
    keep = (m.freq_hz > 20.0) & (m.freq_hz < f_max_hz) & (m.damping < zeta_max)
    return np.sort(m.freq_hz[keep]), m


def test_warp_and_unwarp_are_inverse_and_match_the_bilinear_map():
    f = np.array([1.0, 175.0, 740.0, 1900.0])
    assert_allclose(P.tustin_unwarp_hz(P.tustin_warp_hz(f)), f, rtol=1e-12)
    # a pole at angle 2 pi f / fs on the unit circle, mapped by s = 2 fs (z - 1) / (z + 1)
    z = np.exp(2j * np.pi * f / FS)
    assert_allclose(np.abs(2 * FS * (z - 1) / (z + 1)) / (2 * np.pi), P.tustin_warp_hz(f), rtol=1e-12)
    assert_allclose(P.STAGE_MODES_HZ, P.tustin_unwarp_hz(P.PAPER_MODES_HZ), rtol=0)
    assert 173.5 < P.STAGE_MODES_HZ[0] < 174.5 and 669.0 < P.STAGE_MODES_HZ[5] < 671.5
    with pytest.raises(ValueError, match="f_hz"):
        P.tustin_warp_hz(2000.0)


def test_damping_unwarp_matches_the_exact_pole_map():
    """A true mode (f, zeta) sampled exactly (z = exp(s T)) and converted by Tustin has the paper's damping:
    first order in zeta, to 1e-4 relative at zeta = 0.005."""
    for f, zeta in zip(P.STAGE_MODES_HZ, P.STAGE_MODE_DAMPING_MEAN):
        w = 2 * np.pi * f
        z = np.exp((-zeta * w + 1j * w * np.sqrt(1 - zeta ** 2)) / FS)
        s_w = 2 * FS * (z - 1) / (z + 1)
        assert -s_w.real / abs(s_w) == pytest.approx(zeta / (np.sin(2 * np.pi * f / FS) / (2 * np.pi * f / FS)),
                                                     rel=1e-4)
    assert_allclose(P.tustin_unwarp_damping(np.array(P.PAPER_MODE_DAMPING_MEAN), P.PAPER_MODES_HZ),
                    P.STAGE_MODE_DAMPING_MEAN, rtol=0)


def test_tustin_d2c_of_the_stage_gives_the_papers_modes(twin):
    """The MuJoCo linearization sampled exactly (ZOH at 4 kHz, poles exp(p T)) and converted by Tustin, as
    the paper converted its identified model: its six modes below 1 kHz at the paper's. The warped modes are
    the tan-warped images of the stage's (exact to second order in the damping); the stage's lie within 1 % of
    the unwarped targets (the calibration's largest residual is the 441.4 Hz tilt's, 0.96 %), which the warp's
    slope turns into up to 1.1 % of the paper's."""
    sysd = twin.sysd_V
    true_hz, _ = lightly_damped_hz(sysd.A, sysd.dt)
    cm = ident.d2c_tustin(sysd.A, sysd.B, sysd.C, sysd.D, sysd.dt)
    warped_hz, _ = lightly_damped_hz(cm.A)
    assert len(true_hz) == 6 and len(warped_hz) == 6, (true_hz, warped_hz)
    assert_allclose(true_hz, P.STAGE_MODES_HZ, rtol=0.01)
    assert_allclose(warped_hz, P.tustin_warp_hz(true_hz), rtol=2e-5)     # exact up to O(zeta^2)
    assert_allclose(warped_hz, P.PAPER_MODES_HZ, rtol=0.011)


def test_round_trip_check_is_exact_for_tustin_and_the_plain_check_measures_the_warp():
    """A notch at 175 Hz (zeros at zeta = 0.003): Tustin's image against K(j w) differs by the warp, of order one
    near the notch; against K at the warped frequency (2 / T) tan(w T / 2) it agrees to rounding (1e-9)."""
    from nanosim.design.discretize import discretization_error, discretize_controller, round_trip_error
    w = 2 * np.pi * 175.0
    K = ct.ss(ct.tf([1, 2 * 0.003 * w, w * w], [1, 2 * 0.3 * w, w * w]))
    disc = discretize_controller(K, 1 / FS, "tustin_round_trip")
    assert disc.method == "tustin_round_trip" and disc.within_tol and disc.max_rel_error < 1e-9
    assert round_trip_error(K, disc.Kd, 500.0)[0] < 1e-9
    assert discretization_error(K, disc.Kd, 500.0)[0] > 0.5
    assert disc.errors_by_method["tustin"] > 0.5


def _invariant_zeros(S):
    import scipy.linalg as sl
    A, B, C, D = (np.asarray(getattr(S, k), float) for k in "ABCD")
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    M = np.block([[A, B], [C, D]])
    N = np.block([[np.eye(n), np.zeros((n, m))], [np.zeros((p, n + m))]])
    z = sl.eigvals(M, N)
    return z[np.isfinite(z)]


@pytest.fixture(scope="module")
def paper_design():
    from nanosim.design.architectures.paper import design_paper
    from nanosim.design.lti import load_state_space_npz
    G = load_state_space_npz(MODEL)[1]
    return G, design_paper(G)


def test_paper_controller_notches_sit_on_the_identified_discrete_poles(paper_design):
    """The paper's design inverts the first XY pair; discretized by Tustin (the exact inverse of the design
    model's d2c) its two zeros there coincide with the identified model's discrete poles: |dz| within 1e-4 of
    |z_p - 1| (pole matching would put them at exp(s_p T), 0.6 % higher in frequency: |dz| ~ 6e-3 |z_p - 1|)."""
    from nanosim.design.architectures.common import as_discrete
    G, bench = paper_design
    assert bench.parameters["discretization"] == "tustin_round_trip"
    Gd = as_discrete(G)
    dt = float(Gd.dt)
    poles = np.linalg.eigvals(np.asarray(Gd.A, float))
    pair = sorted({round(float(f), 6): p for p, f in zip(poles, np.angle(poles) / (2 * np.pi * dt))
                   if p.imag > 0 and 150.0 < f < 200.0}.items())
    assert len(pair) == 2, pair
    zeros = _invariant_zeros(bench.K)
    for _, zp in pair:
        dz = np.min(np.abs(zeros - zp))
        assert dz <= 1e-4 * abs(zp - 1.0), (zp, dz)
        # pole matching's image of the same design-model pole, for scale
        s_p = 2 / dt * (zp - 1) / (zp + 1)
        assert abs(np.exp(s_p * dt) - zp) > 50 * dz


@pytest.mark.slow
def test_identification_with_the_papers_procedure_returns_the_papers_modes():
    """``nanosim identify --paper-bands --ideal`` in one call: step + PRBS in the paper's 50/100/200 Hz bands,
    subspace identification per column, Tustin d2c. The continuous model's six modes are the paper's, within the
    1.1 % of the linearization's (test above); the discrete model's are the MuJoCo modes themselves."""
    from nanosim.experiments.sysid import IdentifySettings, identify_stage, merged_modes
    from nanosim.pipeline.identify import tustin_modes
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.modes import modal_analysis
    res = identify_stage(IdentifySettings(seed=0, order_per_column=14, ideal=True, bands_hz=P.PAPER_PRBS_BANDS_HZ))
    got = np.array([m["freq_hz"] for m in tustin_modes(res)])
    assert len(got) == 6, got
    assert_allclose(got, P.PAPER_MODES_HZ, rtol=0.011)
    truth = np.array([m.freq_hz for m in modal_analysis(load_model()).below(1000.0)])
    assert_allclose([m["freq_hz"] for m in merged_modes(res)], truth, rtol=1e-3)
