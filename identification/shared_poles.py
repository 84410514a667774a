"""One pole per structural mode: joint re-estimation of the resonances several column models share.

Identifying a MIMO structure one input at a time (Sec. 3 of the seed paper) gives each column its
own estimate of every resonance. The resonances belong to the structure, not to the actuator, so
the columns' estimates of one mode differ only by error, and a column that barely excites a mode
estimates it worst (on the stage: actuator C and the 462/472 Hz XY pair, estimated 0.4-0.7 % high
with zeta 0.013 instead of 0.004 on some seeds). :func:`refine_shared_poles` groups the lightly
damped poles that several columns share and re-estimates each group's pole from every column's
record at once, by variable projection (Golub & Pereyra 1973): for given poles every column's
output is linear in its residues, feedthrough and initial state, which are eliminated by least
squares; the poles minimise the summed output error, each output weighted by its residual
variance. Poles no other column shares (real creep poles, heavily damped pairs) stay as
identified. The returned columns are in real modal form.

References
----------
G. H. Golub and V. Pereyra, "The differentiation of pseudo-inverses and nonlinear least squares
problems whose variables separate", SIAM J. Numer. Anal. 10(2), 413-432, 1973.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.optimize as _opt
import scipy.signal as _sig

from .checks import as_signal, frozen_array, same_length
from .modal import split_poles
from .regression import observability_powers

__all__ = ["SharedPoles", "refine_shared_poles", "shared_pole_groups", "SHARED_POLE_TOL", "LIGHT_DAMPING"]

# Two columns' poles are one mode when their frequencies differ by at most this fraction: the
# per-column estimates of one mode agree within 1 % (the bench specification's tolerance), while the closest
# distinct modes of the stage are 1.5 % (175.5/178.2 Hz) and 2.0 % (462.7/472.0 Hz) apart.
SHARED_POLE_TOL = 0.01
# a complex pair with a damping ratio below this is a resonance
LIGHT_DAMPING = 0.1


@dataclass(frozen=True, eq=False)
class SharedPoles:
    """Result of :func:`refine_shared_poles`.

    Attributes
    ----------
    columns : tuple of IdentifiedModel
        The column models in real modal form, shared resonances at one pole each.
    freq_hz, damping : numpy.ndarray, shape (n_shared,)
        The refined shared resonances (Hz, damping ratio).
    freq_hz_before, damping_before : numpy.ndarray, shape (n_shared, n_columns)
        Each column's estimate before refinement (NaN where a column lacks the mode).
    cost_before, cost_after : float
        The weighted output error summed over the columns, at the columns' own poles with the
        residues refitted, and at the refined poles (dimensionless: sum of squared residuals
        over residual variances).
    """

    columns: tuple
    freq_hz: np.ndarray
    damping: np.ndarray
    freq_hz_before: np.ndarray
    damping_before: np.ndarray
    cost_before: float
    cost_after: float


def _split_poles(model):
    return split_poles(np.linalg.eigvals(np.asarray(model.A, float)))


def _z_to_hz_zeta(z, dt):
    s = np.log(z) / dt
    return np.abs(s) / (2 * np.pi), -s.real / np.abs(s)


def shared_pole_groups(columns, tol: float = SHARED_POLE_TOL, zeta_max: float = LIGHT_DAMPING) -> list:
    """Group the columns' lightly damped poles into modes seen by at least two columns.

    Parameters
    ----------
    columns : sequence of IdentifiedModel
        Discrete models with a common ``dt_s``.
    tol : float
        Relative frequency tolerance (to a group's lowest member).
    zeta_max : float
        Damping ratio below which a pair is a resonance.

    Returns
    -------
    list of dict
        Per group, ``{column index: discrete pole (upper half plane)}``, sorted by frequency.
    """
    dt = columns[0].dt_s
    light = []
    for j, col in enumerate(columns):
        upper, _ = _split_poles(col)
        f, zeta = _z_to_hz_zeta(upper, dt)
        light += [(float(fk), j, zk) for fk, zk, zt in zip(f, upper, zeta) if zt < zeta_max]
    groups = []
    for f, j, z in sorted(light, key=lambda t: t[0]):
        near = [g for g in groups if j not in g["members"] and abs(f - g["f0"]) <= tol * g["f0"]]
        g = min(near, key=lambda g: abs(f - g["f0"])) if near else None
        if g is None:
            groups.append({"f0": f, "members": {j: z}})
        else:
            g["members"][j] = z
    return [g["members"] for g in groups if len(g["members"]) > 1]


def _regressors(u, upper, real, n):
    """Forced and free responses of ``x+ = lambda x + u`` per pole, and ``u`` (feedthrough)."""
    k = np.arange(n)
    cols = []
    for lam in upper:
        w = _sig.lfilter([0.0, 1.0], [1.0, -lam], u.astype(complex))
        free = np.exp(k * np.log(lam))
        cols += [w.real, w.imag, free.real, free.imag]
    for lam in real:
        cols += [_sig.lfilter([0.0, 1.0], [1.0, -lam], u), lam ** k]
    cols.append(u)
    return np.column_stack(cols)


def _column_fit(u, y, upper, real):
    Phi = _regressors(u, upper, real, len(u))
    norms = np.linalg.norm(Phi, axis=0)
    norms[norms == 0] = 1.0
    theta = np.linalg.lstsq(Phi / norms, y, rcond=None)[0] / norms[:, None]
    return theta, y - Phi @ theta


def _pack(z, dt):
    s = np.log(z) / dt
    return np.array([np.log(abs(s)), np.log(-s.real / abs(s))])


def _unpack(p, dt):
    wn, zeta = np.exp(p[0]), np.exp(p[1])
    return np.exp(dt * complex(-zeta * wn, wn * np.sqrt(max(1.0 - zeta ** 2, 0.0))))


def refine_shared_poles(columns, data, *, tol: float = SHARED_POLE_TOL, zeta_max: float = LIGHT_DAMPING,
                        max_nfev: int = 200) -> SharedPoles:
    """Re-estimate the resonances several columns share, one pole per mode, from all records.

    Parameters
    ----------
    columns : sequence of IdentifiedModel
        Single-input column models with a common ``dt_s`` (from :func:`subspace_id`).
    data : sequence of (u, y)
        Per column its estimation record: ``u`` shape (N,) or (N, 1), ``y`` shape (N, n_outputs),
        in the model's units.
    tol, zeta_max : float
        Grouping, see :func:`shared_pole_groups`.
    max_nfev : int
        Budget of cost evaluations for the nonlinear least squares.

    Returns
    -------
    SharedPoles
        Columns in real modal form: per complex pole ``lambda`` a block ``[[Re, -Im], [Im, Re]]``
        with input row ``[1, 0]``; per real pole a scalar with input 1. ``C``, ``D`` and ``x0``
        are the least-squares fit to the record; ``K`` is the original innovation gain in the
        modal basis.
    """
    if len(columns) == 0:
        raise ValueError("columns: expected at least one column model, got none")
    if len(columns) != len(data):
        raise ValueError(f"data: expected one (u, y) record per column ({len(columns)}), got {len(data)}")
    dt = float(columns[0].dt_s)
    if any(abs(c.dt_s - dt) > 1e-12 * dt for c in columns):
        raise ValueError("columns: expected one common dt_s, got " + ", ".join(str(c.dt_s) for c in columns))
    recs = []
    for j, (col, (u, y)) in enumerate(zip(columns, data)):
        us = as_signal(f"data[{j}] u", u)
        ys = as_signal(f"data[{j}] y", y)
        same_length(f"data[{j}] y", ys, f"data[{j}] u", us)
        if col.B.shape[1] != 1:
            raise ValueError(f"columns[{j}]: expected a single-input model, got {col.B.shape[1]} inputs")
        if us.shape[1] != 1:
            raise ValueError(f"data[{j}] u: expected one input channel, got {us.shape[1]}")
        if ys.shape[1] != col.C.shape[0]:
            raise ValueError(f"data[{j}] y: expected {col.C.shape[0]} outputs, got {ys.shape[1]}")
        recs.append((us[:, 0], ys))
    groups = shared_pole_groups(columns, tol, zeta_max)
    own = []                                   # per column: poles not in a group
    for j, col in enumerate(columns):
        upper, real = _split_poles(col)
        grouped = [g[j] for g in groups if j in g]
        own.append(([z for z in upper if not any(z == gz for gz in grouped)], list(real)))

    def projected(j):
        """Column j's fixed regressors (own poles, feedthrough) projected out of the record."""
        u, y = recs[j]
        F = _regressors(u, own[j][0], own[j][1], len(u))
        Q = np.linalg.qr(F / np.maximum(np.linalg.norm(F, axis=0), 1e-300))[0]
        return Q, y - Q @ (Q.T @ y)

    proj = [projected(j) for j in range(len(recs))]

    def residuals(shared):
        """Per column: the record's part that no combination of the column's regressors explains."""
        out = []
        for j, (u, _) in enumerate(recs):
            Q, y_perp = proj[j]
            S = _regressors(u, [shared[i] for i, g in enumerate(groups) if j in g], [], len(u))[:, :-1]
            S -= Q @ (Q.T @ S)
            S /= np.linalg.norm(S, axis=0)
            out.append(y_perp - S @ np.linalg.lstsq(S, y_perp, rcond=None)[0])
        return out

    # weights: each output's residual variance at the columns' own poles
    own_fits = [_column_fit(u, y, [g[j] for g in groups if j in g] + own[j][0], own[j][1])
                for j, (u, y) in enumerate(recs)]
    scale = [1.0 / np.sqrt(np.maximum(np.mean(r ** 2, axis=0), 1e-12 * np.mean(y ** 2, axis=0) + 1e-300))
             for (_, r), (_, y) in zip(own_fits, recs)]
    cost_before = float(sum(np.sum((r * s) ** 2) for (_, r), s in zip(own_fits, scale)))
    # start: per group, the member of the column whose residual is smallest relative to the mode's response
    start = []
    for g in groups:
        best = max(g, key=lambda j: _mode_strength(own_fits[j][0], [g2[j] for g2 in groups if j in g2]
                                                   + own[j][0], g[j], scale[j]))
        start.append(g[best])

    def residual(p):
        shared = [_unpack(p[2 * i:2 * i + 2], dt) for i in range(len(groups))]
        return np.concatenate([(r * s).ravel() for r, s in zip(residuals(shared), scale)])

    if groups:
        p0 = np.concatenate([_pack(z, dt) for z in start])
        sol = _opt.least_squares(residual, p0, x_scale=np.full(p0.shape, 1e-3), diff_step=1e-7,
                                 max_nfev=max_nfev)
        shared = [_unpack(sol.x[2 * i:2 * i + 2], dt) for i in range(len(groups))]
        cost_after = float(2 * sol.cost)
    else:
        shared, cost_after = [], cost_before
    out = []
    for j, ((u, y), col) in enumerate(zip(recs, columns)):
        upper = [shared[i] for i, g in enumerate(groups) if j in g] + own[j][0]
        theta, _ = _column_fit(u, y, upper, own[j][1])
        out.append(_modal_model(col, theta, upper, own[j][1]))
    f_b = np.full((len(groups), len(columns)), np.nan)
    z_b = np.full((len(groups), len(columns)), np.nan)
    for i, g in enumerate(groups):
        for j, z in g.items():
            f_b[i, j], z_b[i, j] = _z_to_hz_zeta(z, dt)
    f_a, z_a = _z_to_hz_zeta(np.array(shared, complex), dt) if groups else (np.zeros(0), np.zeros(0))
    return SharedPoles(columns=tuple(out), freq_hz=frozen_array(f_a), damping=frozen_array(z_a),
                       freq_hz_before=frozen_array(f_b), damping_before=frozen_array(z_b),
                       cost_before=cost_before, cost_after=cost_after)


def _mode_strength(theta, upper, z, scale):
    i = next(k for k, zk in enumerate(upper) if zk == z)
    c = theta[4 * i:4 * i + 2]                 # forced-response coefficients, shape (2, n_outputs)
    return float(np.sum((c * scale) ** 2) / max(1.0 - abs(z), 1e-12))


def _modal_model(col, theta, upper, real):
    nc, nr = len(upper), len(real)
    n = 2 * nc + nr
    l = theta.shape[1]
    A = np.zeros((n, n))
    B = np.zeros((n, 1))
    Cm = np.zeros((l, n))
    for i, lam in enumerate(upper):
        A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[lam.real, -lam.imag], [lam.imag, lam.real]]
        B[2 * i, 0] = 1.0
        Cm[:, 2 * i:2 * i + 2] = theta[4 * i:4 * i + 2].T
    for i, lam in enumerate(real):
        k = 2 * nc + i
        A[k, k] = lam
        B[k, 0] = 1.0
        Cm[:, k] = theta[4 * nc + 2 * i]
    D = theta[-1][:, None]
    x0 = _initial_state(A, Cm, theta, nc, nr)
    K = _modal_gain(col, upper, real)
    return dataclasses.replace(col, A=frozen_array(A), B=frozen_array(B), C=frozen_array(Cm), D=frozen_array(D),
                               K=frozen_array(K), x0=frozen_array(x0), order=n)


def _initial_state(A, Cm, theta, nc, nr):
    """``x0`` whose free response ``C A^k x0`` best matches the fitted free-response terms."""
    n, l = A.shape[0], Cm.shape[0]
    # free response of the fitted model over 2n samples, then x0 from the observability matrix
    k = np.arange(2 * n)
    y_free = np.zeros((2 * n, l))
    for i in range(nc):
        lam = complex(A[2 * i, 2 * i], A[2 * i + 1, 2 * i])
        y_free += np.outer((lam ** k).real, theta[4 * i + 2]) + np.outer((lam ** k).imag, theta[4 * i + 3])
    for i in range(nr):
        y_free += np.outer(A[2 * nc + i, 2 * nc + i] ** k, theta[4 * nc + 2 * i + 1])
    O = observability_powers(A, Cm, 2 * n)
    return np.linalg.lstsq(O.reshape(-1, n), y_free.reshape(-1), rcond=None)[0]


def _modal_gain(col, upper, real):
    """The column's innovation gain in the new modal basis (each pole matched to the nearest old one)."""
    A0, B0, K0 = (np.asarray(m, float) for m in (col.A, col.B, col.K))
    lam0, V = np.linalg.eig(A0)
    Vi = np.linalg.inv(V)
    b, k = Vi @ B0[:, 0], Vi @ K0
    rows = []
    for idx, lam in enumerate(list(upper) + list(real)):
        i = int(np.argmin(np.abs(lam0 - lam)))
        kw = k[i] / b[i] if abs(b[i]) > 1e-12 * np.max(np.abs(b)) else np.zeros(k.shape[1], complex)
        rows += [kw.real, kw.imag] if idx < len(upper) else [kw.real]      # a 2-state block per complex pole
    return np.array(rows).reshape(len(rows), K0.shape[1])
