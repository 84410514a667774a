"""A test controller shared by the loop tests: a leaky integrator through the stage's static gain."""
from __future__ import annotations

import numpy as np

from nanosim.design.controller import ControllerConfig


def integrator_controller(G0_um_per_V, two_dof: bool = False, f_hz: float = 20.0,
                          leak: float = 0.9995) -> ControllerConfig:
    """Leaky integrator ``u = g (r - y)`` through ``inv(G0)`` with crossover about ``f_hz``, at 4 kHz.

    ``g = 2 pi f T G0^-1`` (controller V per sensor V, 5 um/V), the state leaking by ``leak`` per sample.
    ``two_dof``: a second state block low-passes the measurement (pole 0.95) and feeds it back with gain
    ``0.3 g``, so the controller's reference and measurement paths differ (a two-degree-of-freedom controller).
    """
    T = 2.5e-4
    g = 2 * np.pi * f_hz * T * np.linalg.inv(np.asarray(G0_um_per_V) / 5.0)
    if not two_dof:
        return ControllerConfig(leak * np.eye(3), np.eye(3), g, g, T)
    a = 0.95
    A = np.block([[leak * np.eye(3), np.zeros((3, 3))], [np.zeros((3, 3)), a * np.eye(3)]])
    B = np.block([[np.eye(3), np.zeros((3, 3))], [np.zeros((3, 3)), (1 - a) * np.eye(3)]])
    return ControllerConfig(A, B, np.hstack([g, 0.3 * g]), np.hstack([g, -0.3 * g]), T, n_error=3)
