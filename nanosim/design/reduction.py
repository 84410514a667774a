"""Model reduction (paper Sec. 4.1, Figs. 8-10).

* :func:`reduce_model` -- balanced truncation with matched DC gain (singular
  perturbation of the balanced realization, slycot ``ab09nd``) of the identified
  model (paper: 39 states) to the design order (paper: 10 states; Figs. 8-9).
* :func:`multiplicative_uncertainty` -- ``sigma_max(E_o)``,
  ``E_o = (G_P - G) G^-1`` (paper Fig. 10).

Units: see :mod:`nanosim.design.lti` (controller V -> sensor V, frequencies in Hz).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from nanosim.design.lti import as_ss, dc_gain, freqresp, max_real_pole, single_threaded_blas

__all__ = ["Reduction", "reduce_model", "multiplicative_uncertainty"]


@dataclass(frozen=True, eq=False)
class Reduction:
    """Result of :func:`reduce_model` (paper Sec. 4.1, Figs. 8-9).

    Attributes
    ----------
    G_full, G_reduced : control.StateSpace
        Full and reduced models (controller V -> sensor V), continuous.
    full_order, order : int
        Number of states of the full and of the reduced model.
    hankel_sv : ndarray, shape (n_stable,)
        Hankel singular values of the (stable part of the) full model,
        descending; units of the plant gain (sensor V / controller V).
    n_unstable : int
        Poles with ``Re p >= alpha`` (unstable or within ``stability_margin`` of the
        imaginary axis) that were kept unreduced.
    unstable_poles : ndarray, complex, shape (n_unstable,)
        Those poles [rad/s].
    dc_gain_full, dc_gain_reduced : ndarray, shape (ny, nu)
        ``G(0) = D - C A^-1 B`` [sensor V / controller V].
    dc_gain_rel_error : float
        ``max|G_r(0) - G(0)| / max|G(0)|``.
    dc_gain_matched : bool
        ``dc_gain_rel_error <= dc_rtol``.
    error_bound_hinf : float
        Balanced-truncation/SPA bound ``2 * sum(dropped Hankel SVs)`` on
        ``||G - G_r||_inf`` (sensor V / controller V).
    reduced_stable : bool
        All reduced-model poles have negative real part (when the full model is stable).
    method : str
        Description of the algorithm.
    """

    G_full: Any
    G_reduced: Any
    full_order: int
    order: int
    hankel_sv: np.ndarray
    n_unstable: int
    unstable_poles: np.ndarray
    dc_gain_full: np.ndarray
    dc_gain_reduced: np.ndarray
    dc_gain_rel_error: float
    dc_gain_matched: bool
    error_bound_hinf: float
    reduced_stable: bool
    method: str = "balanced truncation with matched DC gain (singular perturbation), slycot ab09nd"

    @property
    def hsv_kept(self) -> np.ndarray:
        """Hankel singular values of the retained stable states."""
        return self.hankel_sv[: max(self.order - self.n_unstable, 0)]

    @property
    def hsv_dropped(self) -> np.ndarray:
        """Hankel singular values of the removed states."""
        return self.hankel_sv[max(self.order - self.n_unstable, 0):]


@single_threaded_blas
def reduce_model(G, order: int = 10, *, stability_margin: float = 1e-8, dc_rtol: float = 1e-6) -> Reduction:
    """Balanced truncation with DC gain matched (paper Sec. 4.1).

    Calls ``control.balanced_reduction(G, order, method='matchdc')`` (slycot
    ``ab09nd``: square-root balancing, then singular perturbation of the weak
    states, so that ``G_r(0) = G(0)``) and ``control.hankel_singular_values``.

    Parameters
    ----------
    G : control.StateSpace
        Full continuous model, ``ny x nu`` (paper: 3x3, 39 states), controller V ->
        sensor V.
    order : int, default 10
        States of the reduced model (paper: 10).
    stability_margin : float, default 1e-8
        Poles with ``Re p >= -stability_margin * max(1, max|p|)`` are treated as the
        unstable part: they are kept unchanged (``ab09nd`` with
        ``alpha = -stability_margin * max(1, max|p|)``) and counted in ``order``.
    dc_rtol : float, default 1e-6
        Relative tolerance of the DC-gain check.

    Returns
    -------
    Reduction

    Raises
    ------
    ValueError
        Bad ``order``; a pole at (or numerically at) ``s = 0``, for which the DC gain
        is infinite and DC matching undefined; or more unstable/marginal poles than
        ``order``.

    Warns
    -----
    UserWarning
        When the full model has unstable or near-imaginary-axis poles (kept
        unreduced), when the DC gain is not matched to ``dc_rtol``, or when slycot
        returns fewer states than requested (the model is non-minimal).
    """
    import control as ct
    G = as_ss("G", G)
    n = G.nstates
    if isinstance(order, bool) or not float(order).is_integer() or not 1 <= int(order) <= n:
        raise ValueError(f"order: expected an integer in [1, {n}] (full model order), got {order!r}")
    order = int(order)
    A = np.asarray(G.A, dtype=float)
    poles = np.linalg.eigvals(A)
    rho = max(1.0, float(np.max(np.abs(poles))) if n else 1.0)
    alpha = -stability_margin * rho
    at_origin = np.abs(poles) <= max(stability_margin * rho, 1e-12)
    if np.any(at_origin):
        raise ValueError(
            f"G: the full model has {int(at_origin.sum())} pole(s) at s ~ 0 "
            f"(|p| <= {stability_margin * rho:.2g} rad/s), "
            f"e.g. an integrator or drift left by the identification. Its DC gain is infinite, so "
            f"DC-matched balanced truncation is undefined. Remove the pole (e.g. refit with a stable "
            f"model, or shift it to s = -eps) before reducing.")
    unstable = poles[poles.real >= alpha]
    n_unst = int(unstable.size)
    if n_unst:
        warnings.warn(
            f"G has {n_unst} unstable or near-imaginary-axis pole(s) (Re p >= {alpha:.3g} rad/s): "
            f"{np.array2string(unstable, precision=4)}; they are kept unreduced and only the stable part "
            f"is balanced and truncated. Check the identified model.", UserWarning, stacklevel=2)
        if n_unst > order:
            raise ValueError(
                f"G: the full model has {n_unst} unstable/marginal poles but order={order}; the reduced "
                f"order must be at least {n_unst} because unstable poles cannot be truncated")
    Gr = ct.balanced_reduction(G, order, method="matchdc", alpha=alpha)
    Gr = ct.ss(Gr.A, Gr.B, Gr.C, Gr.D)
    if Gr.nstates != order:
        warnings.warn(f"balanced_reduction returned {Gr.nstates} states instead of {order} (the full model is "
                      f"non-minimal: fewer than {order} Hankel singular values are nonzero)", UserWarning, stacklevel=2)
    if n_unst == 0:
        hsv = np.real(np.asarray(ct.hankel_singular_values(G), dtype=complex))
    else:
        from slycot import ab09nd
        m, p = G.ninputs, G.noutputs
        out = ab09nd("C", "B", "N", n, m, p, A, np.asarray(G.B, float), np.asarray(G.C, float),
                     np.asarray(G.D, float), alpha=alpha, nr=order, tol1=0.0, tol2=0.0)
        hsv = np.asarray(out[-1], dtype=float)[: n - n_unst]
    hsv = np.sort(np.clip(hsv, 0.0, None))[::-1]
    dc_full, dc_red = dc_gain(G), dc_gain(Gr)
    scale = float(np.max(np.abs(dc_full))) or 1.0
    rel = float(np.max(np.abs(dc_red - dc_full)) / scale)
    if rel > dc_rtol:
        warnings.warn(f"reduced DC gain differs from the full one by {rel:.3g} (relative) > {dc_rtol:g}",
                      UserWarning, stacklevel=2)
    kept_stable = max(Gr.nstates - n_unst, 0)
    bound = float(2.0 * np.sum(hsv[kept_stable:]))
    red_stable = bool(max_real_pole(Gr.A) < 0) if Gr.nstates else True
    return Reduction(G_full=G, G_reduced=Gr, full_order=n, order=int(Gr.nstates), hankel_sv=hsv,
                     n_unstable=n_unst, unstable_poles=unstable, dc_gain_full=dc_full, dc_gain_reduced=dc_red,
                     dc_gain_rel_error=rel, dc_gain_matched=rel <= dc_rtol, error_bound_hinf=bound,
                     reduced_stable=red_stable)


@single_threaded_blas
def multiplicative_uncertainty(G_full, G_nom, freq_hz) -> np.ndarray:
    """Largest singular value of the output multiplicative error (paper Fig. 10).

    ``G_P = (I + E_o) G``  =>  ``E_o = (G_P - G) G^-1`` with ``G_P = G_full`` (the
    "actual" plant) and ``G = G_nom`` (reduced, nominal).

    Parameters
    ----------
    G_full, G_nom : control.StateSpace
        Square ``n x n`` continuous models with the same dimensions.
    freq_hz : array_like, shape (F,)
        Frequencies [Hz].

    Returns
    -------
    ndarray, shape (F,)
        ``sigma_max(E_o(j 2 pi f))`` [dimensionless]; ``inf`` where ``G_nom`` is
        singular.
    """
    G_full = as_ss("G_full", G_full)
    G_nom = as_ss("G_nom", G_nom)
    if G_nom.noutputs != G_nom.ninputs:
        raise ValueError(f"G_nom: E_o needs a square plant, got {G_nom.noutputs}x{G_nom.ninputs}")
    if (G_full.noutputs, G_full.ninputs) != (G_nom.noutputs, G_nom.ninputs):
        raise ValueError(f"G_full is {G_full.noutputs}x{G_full.ninputs} but G_nom is {G_nom.noutputs}x{G_nom.ninputs}")
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1 or not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError("freq_hz: expected a 1-D array of finite frequencies >= 0 Hz")
    Gp, G0 = freqresp(G_full, f), freqresp(G_nom, f)
    out = np.full(f.size, np.inf)
    for k in range(f.size):
        try:
            # E G0 = (Gp - G0)  =>  G0^T E^T = (Gp - G0)^T
            E = np.linalg.solve(G0[k].T, (Gp[k] - G0[k]).T).T
            out[k] = np.linalg.norm(E, 2)
        except np.linalg.LinAlgError:
            pass
    return out
