"""(b) hinf-damped: H-infinity with the paper's weights around an inner damping loop (a bench member; the
exported default is ``hinf``, :mod:`.hinf_fourblock`).

Tuning rule (README "Controller"): DC-matched balanced truncation to 14 states; an inner
band-limited velocity feedback ``Ky`` adding ``zeta = 0.1`` to the first lightly damped
mode (400 Hz low-pass, :func:`~nanosim.design.damping.damping_loop`); the paper's
mixed-sensitivity weights on the damped plant ``(I - G Ky)^-1 G``; ``u = K e + Ky y``.
With ``delay_aware`` (default) the design model carries ``delay_samples`` (0 for a model of
``nanosim identify``, which is the loop as run; ``d`` for a model from record rows): ``z^-d`` is,
under the Tustin map the controller is discretized with, the all-pass
``((1 - s dt/2)/(1 + s dt/2))^d`` at every input, so the H-infinity problem sees the
loop as it is run. If the pipeline's damping loop is unstable with that delay, the first
stable one of a fallback grid is used (less added damping first, then a higher low-pass).
"""
from __future__ import annotations

import numpy as np

from nanosim.constants import DEFAULT_DAMPING_LOWPASS_HZ, DEFAULT_DAMPING_ZETA, DEFAULT_REDUCED_ORDER
from nanosim.design.architectures.common import DT_S, IDENTIFIED_DELAY_SAMPLES, BenchDesign, as_continuous
from nanosim.design.damping import damped_plant, damping_loop
from nanosim.design.discretize import discretize_controller
from nanosim.design.hinf import design_hinf
from nanosim.design.loops import stack_inputs
from nanosim.design.lti import single_threaded_blas
from nanosim.design.reduction import reduce_model
from nanosim.design.weights import Weights

__all__ = ["design_hinf_damped", "tustin_delay", "TUNING_RULE", "REDUCED_ORDER", "DAMPING_ZETA",
           "DAMPING_LOWPASS_HZ"]

# the pipeline's defaults (nanosim.pipeline.config.DesignConfig(), defined in nanosim.constants)
REDUCED_ORDER = DEFAULT_REDUCED_ORDER
DAMPING_ZETA = DEFAULT_DAMPING_ZETA
DAMPING_LOWPASS_HZ = DEFAULT_DAMPING_LOWPASS_HZ
# when the pipeline's damping loop is unstable with the loop's delay: less added damping, then a higher low-pass
FALLBACK_ZETAS = (0.05, 0.03, 0.02)
FALLBACK_LOWPASS_HZ = (500.0, 600.0, 800.0, 1000.0)
TUNING_RULE = (f"{REDUCED_ORDER}-state model, damping loop adding zeta {DAMPING_ZETA:g} to the first mode "
               f"({DAMPING_LOWPASS_HZ:g} Hz low-pass; less damping, then "
               "a higher low-pass, if that inner loop is unstable with the loop's delay), optimal H-infinity with the "
               "paper's weights on the damped plant; design model = the identified model, the loop as run")


def tustin_delay(n: int, delay_samples: int, dt: float):
    """``((1 - s dt/2)/(1 + s dt/2))^d I_n``: the Tustin image of ``z^-d`` (continuous, ``n`` channels)."""
    import control as ct
    if delay_samples < 0:
        raise ValueError(f"delay_samples: expected an integer >= 0, got {delay_samples!r}")
    if delay_samples == 0:
        return ct.ss(np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), np.eye(n))
    one = ct.ss(ct.tf([-dt / 2, 1.0], [dt / 2, 1.0]))
    d = one
    for _ in range(delay_samples - 1):
        d = ct.series(d, one)
    from scipy.linalg import block_diag
    A = block_diag(*[np.asarray(d.A)] * n)
    B = block_diag(*[np.asarray(d.B)] * n)
    C = block_diag(*[np.asarray(d.C)] * n)
    D = block_diag(*[np.asarray(d.D)] * n)
    return ct.ss(A, B, C, D)


def _stable_damping_loop(G_design, G_loop, zeta: float, lowpass_hz: float):
    """The pipeline's damping loop, or the first of a fallback grid that is stable on ``G_loop``."""
    tried = []
    for z in (zeta,) + tuple(v for v in FALLBACK_ZETAS if v < zeta):
        for lp in (lowpass_hz,) + tuple(v for v in FALLBACK_LOWPASS_HZ if v > lowpass_hz):
            dl = damping_loop(G_design, z, lowpass_hz=lp)
            try:
                return dl, damped_plant(G_loop, dl)
            except ValueError:
                tried.append((z, lp))
    raise ValueError(f"G: no damping loop of the grid (zeta_added, lowpass_hz) {tried} is stable with the loop's "
                     f"delay")


@single_threaded_blas
def design_hinf_damped(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES,
                       reduced_order: int = REDUCED_ORDER, damping_zeta: float = DAMPING_ZETA,
                       damping_lowpass_hz: float = DAMPING_LOWPASS_HZ, weights=None,
                       delay_aware: bool = True) -> BenchDesign:
    """H-infinity around the damping loop (see the module docstring).

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (continuous, or discrete: mapped by inverse Tustin), 3 x 3.
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples] put into the design model when ``delay_aware``.
    reduced_order, damping_zeta, damping_lowpass_hz, weights
        As :class:`nanosim.pipeline.config.DesignConfig`.
    delay_aware : bool
        Design with the loop's delay (False: today's pipeline design).

    Returns
    -------
    BenchDesign
        Two-degree-of-freedom controller, inputs ``[e; y]``.
    """
    import control as ct
    Gc = as_continuous(G)
    red = reduce_model(Gc, reduced_order)
    Gr = red.G_reduced
    d_design = delay_samples if delay_aware else 0
    if d_design:
        Gr = ct.ss(ct.series(tustin_delay(Gr.ninputs, d_design, dt), Gr))
    dl, Gdamped = _stable_damping_loop(red.G_reduced, Gr, damping_zeta, damping_lowpass_hz)
    d = design_hinf(Gdamped, Weights.coerce(weights))
    disc = discretize_controller(d.K, dt, "auto")
    disc_y = discretize_controller(dl.Ky, dt, "tustin_modal")    # Ky(z = 1) = 0 exactly
    K2 = stack_inputs(disc.Kd, disc_y.Kd)
    params = {"reduced_order": red.order, "gamma": d.gamma, "controller_order": int(K2.nstates),
              "damping_loop": dl.to_dict(), "design_bandwidth_S_hz": d.bandwidth_S_hz,
              "design_bandwidth_T_hz": d.bandwidth_T_hz, "discretization": disc.method,
              "design_model_delay_samples": d_design, "loop_delay_samples": delay_samples}
    return BenchDesign("hinf-damped", K2, Gc.noutputs, TUNING_RULE, params)
