"""Models and controllers out of nanosim: MATLAB ``.mat`` state spaces and second-order sections.

Every model and controller a run folder holds as ``.npz`` is also written beside it as
``.mat`` with MATLAB's names: ``A, B, C, D`` and the sample time ``Ts`` [s] (0 for a
continuous model), so ``ss(A, B, C, D, Ts)`` in MATLAB rebuilds it; the channel names and
units ride along as strings (``InputName``, ``OutputName``, ``units``). A controller is also
written as second-order sections per SISO channel (:func:`nanosim.design.sos.state_space_sos`):
``controller_sos.npz`` (``sos`` of shape (n_out, n_in, n_sections, 6), ``dt``, ``n_error``,
``units``) and the same as ``controller_sos.json``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nanosim import fileio

__all__ = ["write_state_space_mat", "mat_beside", "write_controller_exports", "CONTROLLER_SOS_NPZ",
           "CONTROLLER_SOS_JSON", "SOS_UNITS"]

CONTROLLER_SOS_NPZ = "controller_sos.npz"
CONTROLLER_SOS_JSON = "controller_sos.json"
SOS_UNITS = {
    "sos": "per channel [output i, input j]: sections [b0, b1, b2, a0, a1, a2] of "
           "prod (b0 + b1 z^-1 + b2 z^-2) / (a0 + a1 z^-1 + a2 z^-2), gain in the first section; "
           "u_i = sum_j K_ij(z) v_j",
    "inputs": "v = [e; y]: e = r - y (n_error columns), then the measurement y, sensor volts (5 um/V)",
    "outputs": "u: controller volts for actuators A, B, C (before the x20 amplifier)",
    "dt": "s",
}


def mat_beside(path) -> Path:
    """``model.npz`` -> ``model.mat``."""
    return Path(path).with_suffix(".mat")


def write_state_space_mat(path, A, B, C, D, Ts: float, *, input_names=None, output_names=None, units=None,
                          **extra) -> Path:
    """Write ``A, B, C, D, Ts`` (and channel names, units, ``extra`` arrays) as a MATLAB ``.mat`` file.

    Parameters
    ----------
    path : path
        Target ``.mat`` file (written atomically).
    A, B, C, D : array_like
        The state space.
    Ts : float
        Sample time [s]; 0 for a continuous model (MATLAB's convention).
    input_names, output_names : sequence of str, optional
        Written as cell arrays ``InputName``, ``OutputName``.
    units : str, optional
        What the inputs and outputs are, in words.
    """
    data = {k: np.atleast_2d(np.asarray(v, float)) for k, v in zip("ABCD", (A, B, C, D))}
    data["Ts"] = float(Ts)
    if input_names is not None:
        data["InputName"] = np.array([str(n) for n in np.ravel(input_names)], dtype=object)
    if output_names is not None:
        data["OutputName"] = np.array([str(n) for n in np.ravel(output_names)], dtype=object)
    if units is not None:
        data["units"] = str(units)
    data.update(extra)
    return fileio.write_mat(path, data)


def write_controller_exports(npz_path, Akd, Bkd, Ckd, Dkd, dt: float, n_error: int, *, sos: bool = True) -> list:
    """Beside ``controller.npz``: ``controller.mat`` and (with ``sos``) the second-order sections.

    Returns
    -------
    list of Path
        The files written.
    """
    from nanosim.design.sos import state_space_sos
    npz_path = Path(npz_path)
    n_in = np.atleast_2d(Dkd).shape[1]
    inputs = [f"e{k + 1}" for k in range(n_error)] + [f"y{k + 1}" for k in range(n_in - n_error)]
    out = [write_state_space_mat(mat_beside(npz_path), Akd, Bkd, Ckd, Dkd, dt, input_names=inputs,
                                 output_names=["uA", "uB", "uC"][:np.atleast_2d(Dkd).shape[0]],
                                 units=SOS_UNITS["inputs"] + "; " + SOS_UNITS["outputs"], n_error=int(n_error))]
    if sos:
        S = state_space_sos(Akd, Bkd, Ckd, Dkd)
        folder = npz_path.parent
        out.append(fileio.write_npz(folder / CONTROLLER_SOS_NPZ, sos=S, dt=np.float64(dt), n_error=np.int64(n_error),
                                    input_names=np.array(inputs), units=np.array(str(SOS_UNITS))))
        out.append(fileio.write_json(folder / CONTROLLER_SOS_JSON,
                                     {"sos": S.tolist(), "dt": float(dt), "n_error": int(n_error), "inputs": inputs,
                                      "outputs": ["A", "B", "C"][:S.shape[0]], "units": SOS_UNITS}))
    return out
