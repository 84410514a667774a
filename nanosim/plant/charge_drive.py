"""The charge amplifier: the piezo driven by charge above a crossover frequency, by voltage below it.

A piezoelectric actuator's strain is close to linear in its charge; the hysteresis (and the creep) sits
mostly between the applied voltage and the charge. A charge amplifier regulates the charge instead of the
voltage (Comstock, US patent 4,263,527, 1981; Newcomb & Flinn, Electron. Lett. 18, 442 (1982)), which
reduces the hysteresis about five-fold (Fleming & Leang, *Design, Modeling and Control of Nanopositioning
Systems*, Springer 2014, Ch. 12 "Charge Drives", citing Ge & Jouaneh 1996 and Fleming 2010; 84-90 % less
from 0.05 to 10 Hz in Zhang et al., Electron. Lett. 48, 697 (2012)).

The circuit (Fleming & Moheimani, Rev. Sci. Instrum. 76, 073707 (2005)): the load current is the current of
a sensing capacitor ``C_s``, shunted by ``R_s`` so that the piezo (``C_p``, shunted by ``R_p``) has a DC
path. With ``R_s C_s = R_p C_p = tau`` and the command referred to piezo volts, ``v = (C_s / C_p) v_ref``,
the load charge ``q = C_p x`` (``x``: the charge in piezo volts, the strain the mechanics sees) obeys::

    tau dx/dt + v_p = tau dv/dt + v,        x = P[v_p]

with ``P`` the piezo's voltage-to-strain operator (:mod:`nanosim.plant.piezo`, hysteresis and creep). Above
``f_c = 1 / (2 pi tau)`` the charge follows the command (``x = v``); below it the resistors set the voltage
(``v_p = v``, ``x = P[v]``): the charge amplifier becomes a voltage amplifier and the hysteresis returns.
Writing ``P[v] = v + d[v]`` (``d``: the hysteresis and creep of the voltage drive, about 15 % of the stroke
over the Fig. 14 loop) and keeping the first order in ``d``, ``x = v + LP[d[v]]`` with the first-order
low-pass ``LP = 1 / (1 + s tau)``: the complementary split of the drive into a voltage-driven part below
``f_c`` and a charge-driven part above it. The strain is not exactly linear in the charge either; a
fraction ``rho`` of the hysteresis survives the charge drive (the residual the papers measure)::

    x = P[v] - (1 - rho) HP[P[v] - v],       HP = 1 - LP = s tau / (1 + s tau)

At DC ``x = P[v]``, the voltage drive exactly; well above ``f_c`` ``x = v + rho d + (1 - rho) LP[d]``. The
linear gain is the piezo's loop secant, 1 (:attr:`~nanosim.plant.piezo.PiezoConfig.normalize_loop_slope`),
so a loop's travel is that of the voltage drive. ``LP`` is the exact zero-order-hold discretisation of the
first-order lag at the controller rate, ``y_k = a y_{k-1} + (1 - a) d_k``, ``a = exp(-2 pi f_c T)``.

Parameters and their sources (:mod:`nanosim.constants`): the residual fraction ``rho = 0.2``
(:data:`~nanosim.constants.CHARGE_RESIDUAL_HYSTERESIS`, the five-fold reduction above); the crossover
``f_c = 0.1 Hz`` (:data:`~nanosim.constants.CHARGE_CROSSOVER_HZ`), set by ``R_p = 1 / (2 pi f_c C_p)``
with the APA35XS capacitance (:data:`~nanosim.constants.PIEZO_CAPACITANCE_F`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

__all__ = ["ChargeDrive", "DRIVES"]

DRIVES = ("voltage", "charge")


class ChargeDrive:
    """The charge amplifier's correction of the piezo's output, for ``n_channels`` actuators.

    Parameters
    ----------
    crossover_Hz : float
        ``f_c = 1 / (2 pi R_p C_p)``: below it the drive is a voltage drive, Hz.
    residual : float
        Fraction ``rho`` of the voltage drive's hysteresis left above ``f_c`` (0 ... 1).
    dt_s : float
        Sample period, s.
    n_channels : int
        Number of actuators.
    """

    def __init__(self, crossover_Hz: float, residual: float, dt_s: float, n_channels: int):
        self.n_channels = int(n_channels)
        self._a = math.exp(-2.0 * math.pi * float(crossover_Hz) * float(dt_s))
        self._b = 1.0 - self._a
        self._keep = 1.0 - float(residual)          # the part of HP[d] the charge removes
        self.reset()

    def reset(self) -> None:
        """No charge history: the low-passed deviation at 0 V."""
        self._y = np.zeros(self.n_channels)

    def step(self, v_piezo_V: np.ndarray, v_free_V: np.ndarray) -> np.ndarray:
        """Strain voltage for one sample: ``P[v] - (1 - rho) HP[P[v] - v]``, shape ``(n_channels,)``."""
        d = v_free_V - v_piezo_V
        # the arithmetic of lfilter([1 - a], [1, -a]) in direct form II transposed: step == run bit for bit
        y = self._b * d + self._y
        self._y = 0.0 * d - (-self._a) * y
        return v_free_V - self._keep * (d - y)

    def run(self, v_piezo_V: np.ndarray, v_free_V: np.ndarray) -> np.ndarray:
        """The same over ``(N, n_channels)`` samples."""
        if not len(v_free_V):
            return v_free_V
        d = v_free_V - v_piezo_V
        y, zf = lfilter([self._b], [1.0, -self._a], d, axis=0, zi=self._y[None, :])
        self._y = zf[0]
        return v_free_V - self._keep * (d - y)
