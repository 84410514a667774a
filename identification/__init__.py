"""System identification toolkit for lightly damped MIMO plants.

Usable on any input/output record (it does not depend on the simulator).
Follows Section 3 of the seed paper: multi-band PRBS + step excitation,
discrete subspace identification of each 3x1 column, the fit factor, the
inverse Tustin transform to continuous time, and a non-parametric H1 check.

Conventions: signals are arrays of shape ``(n_samples, n_channels)`` (1-D =
one channel), sampling frequency keyword ``fs`` in Hz, results are frozen
dataclasses holding read-only arrays.

Example
-------
>>> import identification as ident                                # doctest: +SKIP
>>> ex = ident.paper_excitation(fs=4000.0, amplitude=0.5, seed=0)  # doctest: +SKIP
>>> y = ...  # measured (n_samples, 3) response to ex.u            # doctest: +SKIP
>>> model = ident.subspace_id(y, ex.u, fs=ex.fs)                  # doctest: +SKIP
>>> ident.fit_percent(y, ident.simulate(model, ex.u, model.x0))   # doctest: +SKIP
>>> sysc = ident.d2c(model)  # continuous control.StateSpace      # doctest: +SKIP
"""
from .d2c import ContinuousModel, d2c, d2c_tustin, d2c_zoh
from .fit import fit_percent
from .freq import H1Estimate, frequency_response, h1_estimate
from .modal import Modes, continuous_poles, modes_from_model
from .records import Record, load_record, load_state_space, record_from_arrays
from .residual import ResidualSpectrum, input_referred_residual
from .signals import Excitation, Spectrum, paper_excitation, prbs, prbs_channels, prbs_hold_samples, signal_spectrum
from .shared_poles import LIGHT_DAMPING, SharedPoles, refine_shared_poles, shared_pole_groups
from .simulation import estimate_x0, predict, simulate
from .subspace import IdentifiedModel, default_horizon, select_order, subspace_id

__all__ = [
    "prbs",
    "prbs_channels",
    "prbs_hold_samples",
    "paper_excitation",
    "Excitation",
    "signal_spectrum",
    "Spectrum",
    "subspace_id",
    "select_order",
    "default_horizon",
    "IdentifiedModel",
    "simulate",
    "estimate_x0",
    "predict",
    "d2c_tustin",
    "d2c_zoh",
    "d2c",
    "ContinuousModel",
    "fit_percent",
    "h1_estimate",
    "H1Estimate",
    "frequency_response",
    "input_referred_residual",
    "ResidualSpectrum",
    "modes_from_model",
    "continuous_poles",
    "Modes",
    "refine_shared_poles",
    "shared_pole_groups",
    "SharedPoles",
    "LIGHT_DAMPING",
    "Record",
    "load_record",
    "record_from_arrays",
    "load_state_space",
]
