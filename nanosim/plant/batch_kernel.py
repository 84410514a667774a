"""The closed loop of a batch of linear twins compiled with numba: one call per block of periods.

:func:`twin_closed_loop` runs the loop of
:func:`nanosim.experiments.batch_loop.run_closed_loop_batch` (controller bank,
then :meth:`BatchTwinStage.step`: computation delay, DAC quantiser and noise,
amplifier noise, saturation, gain, amplifier lag, piezo operators, linear
creep, twin, floor vibration, gauge filter, gauge noise, clip, ADC) for every
member without returning to Python between periods. Every element-wise
operation is the numpy path's, in its order (the piezo operators are the
single stage's compiled :func:`~nanosim.plant.piezo.play_channel`, the creep
sum left to right), and the noise
terms are the same rows (drawn in blocks from the same streams). The matrix
products are the numpy path's: BLAS calls made from compiled code for the
controllers, shared twins and the exact per-member products (one ``gemv``
per member), and :func:`member_products` for per-member twins and floors
with ``exact=False`` (left-to-right sums with the members in the inner loop,
which :func:`nanosim.plant.batch.member_products` repeats in numpy). So the
records equal the numpy path's bit for bit (``tests/test_batch_kernel.py``),
and B = 1 equals :class:`~nanosim.plant.twin.TwinStage`.

Without numba (``AVAILABLE`` False) callers use the numpy path.
"""
from __future__ import annotations

import numpy as np

from nanosim import constants as C
from nanosim.plant.piezo import play_channel

try:                                   # pragma: no cover - exercised where numba is installed
    from numba import njit
    AVAILABLE = True
except ImportError:                    # pragma: no cover
    AVAILABLE = False

    def njit(*args, **kwargs):
        """Stand-in decorator without numba."""
        return (lambda f: f) if not args or not callable(args[0]) else args[0]

__all__ = ["AVAILABLE", "BLOCK", "actuate_period", "electronics_params", "flicker_cascade", "pairwise_sum",
           "sense_period", "supported", "twin_closed_loop", "twin_open_loop"]

BLOCK = 4096                # periods per compiled call (bounds the pre-drawn noise rows)

# integer switches (ip) and scalars (fp) of the electronics
(I_QUANT, I_SAT, I_IMPLIED, I_LAG, I_HYST, I_CREEP, I_DACN, I_AMPN, I_GFILT, I_GNOISE, I_CLIP, I_ADC,
 I_DELAY) = range(13)
(F_CENTER, F_LSB, F_CLO, F_CHI, F_LO, F_HI, F_GAIN, F_LAG_1MA, F_LAG_NA, F_LAG_M, F_W0, F_CSCALE, F_RANGE,
 F_UMV, F_ADC_LSB, F_ADC_LSB_UM, F_ADC_LO, F_ADC_HI, F_LOOP_UMV) = range(19)


@njit(cache=True)
def pairwise_sum(v):
    """Pairwise summation as numpy does it of a contiguous 1-D array of at most 128 elements, bit for bit."""
    n = v.shape[0]
    if n < 8:
        s = 0.0
        for i in range(n):
            s += v[i]
        return s
    r0, r1, r2, r3, r4, r5, r6, r7 = v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]
    i = 8
    m = n - (n % 8)
    while i < m:
        r0 += v[i]
        r1 += v[i + 1]
        r2 += v[i + 2]
        r3 += v[i + 3]
        r4 += v[i + 4]
        r5 += v[i + 5]
        r6 += v[i + 6]
        r7 += v[i + 7]
        i += 8
    s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        s += v[i]
        i += 1
    return s


@njit(cache=True)
def _matvec(M, x, out):
    """Set out = M @ x: the BLAS ``gemv`` numpy's stacked ``matmul`` makes for one member (into ``out``)."""
    np.dot(M, x, out)


@njit(cache=True, error_model="numpy")
def member_products(PS, XT, OUT):
    """``OUT[:, b] = P_b @ XT[:, b]`` for every member of the members-last stack ``PS`` ``(m, k, B)``:
    each sum left to right over ``k``, a multiply then an add per term (no fused multiply-add), the
    members in the inner loop (SIMD across members); :func:`nanosim.plant.batch.member_products` is
    the same arithmetic in numpy.
    """
    m, k, nb = PS.shape
    k4 = 1 + (k - 1) // 4 * 4
    for i in range(m):
        for b in range(nb):
            OUT[i, b] = PS[i, 0, b] * XT[0, b]
        for j in range(1, k4, 4):       # four terms per pass: the same order, a quarter of the stores
            for b in range(nb):
                OUT[i, b] = (((OUT[i, b] + PS[i, j, b] * XT[j, b]) + PS[i, j + 1, b] * XT[j + 1, b])
                             + PS[i, j + 2, b] * XT[j + 2, b]) + PS[i, j + 3, b] * XT[j + 3, b]
        for j in range(k4, k):
            for b in range(nb):
                OUT[i, b] = OUT[i, b] + PS[i, j, b] * XT[j, b]


@njit(cache=True, error_model="numpy")
def actuate_period(uu, kk, ip, fp, dbuf, dacn, ampn, lag_v, pr, pw, pom, pp, z, hcr, csc, ca, cb, cx, v_pz, v_free,
                   satv):
    """One period of :meth:`BatchElectronics.actuate` on the channel commands ``uu`` (delayed in place)."""
    nch = uu.shape[0]
    nd = ip[I_DELAY]
    ncr = csc.shape[0]
    cscale = fp[F_CSCALE]
    center, lsb, clo, chi = fp[F_CENTER], fp[F_LSB], fp[F_CLO], fp[F_CHI]
    lo, hi, gain = fp[F_LO], fp[F_HI], fp[F_GAIN]
    if nd > 0:
        for ch in range(nch):
            x_in = uu[ch]
            uu[ch] = dbuf[0, ch]
            for j in range(nd - 1):
                dbuf[j, ch] = dbuf[j + 1, ch]
            dbuf[nd - 1, ch] = x_in
    for ch in range(nch):
        uc = uu[ch]
        code = 0.0
        code_c = 0.0
        if ip[I_QUANT]:
            code = np.rint((uc - center) / lsb)
            code_c = max(code, clo)
            code_c = min(code_c, chi)
            u_dac = center + code_c * lsb
        else:
            u_dac = uc
        if ip[I_DACN]:
            u_dac = u_dac + dacn[kk, ch]
        u_in = u_dac + ampn[kk, ch] if ip[I_AMPN] else u_dac
        if ip[I_SAT]:
            u_cmd = min(max(u_in, lo), hi)
            s = u_cmd != u_in
            if ip[I_QUANT] and not ip[I_IMPLIED]:
                s = s or (code_c != code)
        else:
            u_cmd = u_in
            s = (code_c != code) if ip[I_QUANT] else False
        satv[ch] = s
        vin = gain * u_cmd
        if ip[I_LAG]:
            vk = lag_v[ch]
            lag_v[ch] = vin * fp[F_LAG_1MA] - vk * fp[F_LAG_NA]
            v = vin + (vk - vin) * fp[F_LAG_M]
        else:
            v = vin
        v_pz[ch] = v
        v_free[ch] = v
    if ip[I_HYST]:                      # the piezo operators of each channel (z: channels x operators)
        for ch in range(nch):
            v_free[ch] = play_channel(v_pz[ch], z[ch], pr, pw, pom, pp)
    if ip[I_CREEP]:                     # s h + sum_k s c_k x_k left to right; x_k = a_k x_k + b_k h
        for ch in range(nch):
            hcr[ch] = cscale * v_free[ch]
        for j in range(ncr):
            cj, aj, bj = csc[j], ca[j], cb[j]
            for ch in range(nch):
                hcr[ch] = hcr[ch] + cj * cx[j, ch]
                cx[j, ch] = aj * cx[j, ch] + bj * v_free[ch]
        for ch in range(nch):
            v_free[ch] = hcr[ch]


@njit(cache=True, error_model="numpy")
def sense_period(dd, kk, ip, fp, gb, ga, gz, gnoise, y_V, y_um, clip):
    """One sample of :meth:`BatchElectronics.read` of the channel displacements ``dd`` (um)."""
    nch = dd.shape[0]
    go = gz.shape[0]
    for ch in range(nch):
        d = dd[ch]
        if ip[I_GFILT]:
            yf = gz[0, ch] + d * gb[0]
            for i in range(go - 1):
                gz[i, ch] = gz[i + 1, ch] + d * gb[i + 1] - yf * ga[i + 1]
            gz[go - 1, ch] = d * gb[go] - yf * ga[go]
            d = yf
        if ip[I_GNOISE]:
            d = d + gnoise[kk, ch]
        clipped = False
        if ip[I_CLIP]:
            dc = min(max(d, -fp[F_RANGE]), fp[F_RANGE])
            clipped = dc != d
            d = dc
        if ip[I_ADC]:
            code = np.rint(d / fp[F_UMV] / fp[F_ADC_LSB])
            code_c = min(max(code, fp[F_ADC_LO]), fp[F_ADC_HI])
            clipped = clipped or (code_c != code)
            y_V[ch] = code_c * fp[F_ADC_LSB]
            y_um[ch] = code_c * fp[F_ADC_LSB_UM]
        else:
            y_V[ch] = d / fp[F_UMV]
            y_um[ch] = d
        clip[ch] = clipped


@njit(cache=True, error_model="numpy")
def _kernel(n, ref, y, rec, yv, tb, us, sat_rec,
            cmode, CM, xe, ns, ne, two_dof,
            ip, fp, dbuf, dacn, ampn, lag_v, pr, pw, pom, pp, z, csc, ca, cb, cx,
            tmode, TA, TB, TC, TD, TP, tx, home,
            fmode, FA, FB, FC, FP, fx, facc,
            gb, ga, gz, gnoise,
            table, last_pz, last_sat, last_clip, k0, orec, pz_rec, yu_rec, cl_rec):
    nb = y.shape[0]
    nch = 3 * nb
    gain = fp[F_GAIN]
    nx = tx.shape[1]
    nf = fx.shape[1]
    p_out = CM.shape[2] if cmode == 0 else CM.shape[1]
    u = np.empty((nb, 3))
    uu = np.empty(nch)
    v_free = np.empty(nch)
    v_pz = np.empty(nch)
    satv = np.zeros(nch, dtype=np.bool_)
    co = np.empty(p_out)
    XV = np.empty((nb if tmode == 2 else 0, nx + 3))
    XT = np.empty((nx + 3 if tmode == 3 else 0, nb))
    TT = np.empty((nx + 3 if tmode == 3 else 0, nb))
    tall = np.empty((nb if tmode == 2 else 0, nx + 3))
    cout = np.empty((nb if cmode == 0 else 0, p_out))
    xn = np.empty(nx)
    tmp = np.empty(nx)
    yy = np.empty(3)
    ty = np.empty(3)
    FT = np.empty((nf + 3 if fmode == 2 else 0, nb))
    FO = np.empty((nf + 3 if fmode == 2 else 0, nb))
    fn = np.empty(nf)
    ftmp = np.empty(nf)
    d3 = np.empty(3)
    hcr = np.empty(nch)
    dd = np.empty(nch)
    yv_ch = np.empty(nch)
    yu_ch = np.empty(nch)
    cl_ch = np.zeros(nch, dtype=np.bool_)
    for kk in range(n):
        # -- controller bank (BatchController.feedback), or the open-loop command (cmode -1)
        if cmode < 0:
            for b in range(nb):
                for c in range(3):
                    u[b, c] = ref[kk, b, c]
        for b in range(nb if cmode >= 0 else 0):
            for c in range(ne):
                xe[b, ns + c] = ref[kk, b, c] - y[b, c]
            if two_dof:
                for c in range(3):
                    xe[b, ns + ne + c] = y[b, c]
        if cmode < 0:
            pass
        elif cmode == 0:                    # shared, xe @ M.T in one gemm
            np.dot(xe, CM[0], cout)
            for b in range(nb):
                for i in range(ns):
                    xe[b, i] = cout[b, i]
                for c in range(3):
                    u[b, c] = cout[b, ns + c]
        else:
            for b in range(nb):
                _matvec(CM[0] if cmode == 1 else CM[b], xe[b], co)
                for i in range(ns):
                    xe[b, i] = co[i]
                for c in range(3):
                    u[b, c] = co[ns + c]
        if rec and not orec:
            for b in range(nb):
                for c in range(3):
                    yv[b, k0 + kk, c] = y[b, c]
                    tb[b, k0 + kk, c] = table[b, c]
                    us[b, k0 + kk, c] = u[b, c]
        # -- actuators (BatchElectronics.actuate)
        for b in range(nb):
            for c in range(3):
                uu[3 * b + c] = u[b, c]
        actuate_period(uu, kk, ip, fp, dbuf, dacn, ampn, lag_v, pr, pw, pom, pp, z, hcr, csc, ca, cb, cx, v_pz, v_free,
                       satv)
        # -- twin (BatchTwinStage._advance) and floor
        if tmode == 2:                      # shared [x+; y] = P [x; v]: one gemm, [x, v] @ P.T
            for b in range(nb):
                for i in range(nx):
                    XV[b, i] = tx[b, i]
                for c in range(3):
                    XV[b, nx + c] = v_free[3 * b + c] / gain
            np.dot(XV, TP[0], tall)
        elif tmode == 3:                    # per member [x+; y] = P_b [x; v], members last (TP: (m, k, B))
            for b in range(nb):
                for i in range(nx):
                    XT[i, b] = tx[b, i]
                for c in range(3):
                    XT[nx + c, b] = v_free[3 * b + c] / gain
            member_products(TP, XT, TT)
        if fmode == 2:                      # per member [x+; d] = P_b [x; a], members last (FP: (m, k, B))
            for b in range(nb):
                for i in range(nf):
                    FT[i, b] = fx[b, i]
                for c in range(3):
                    FT[nf + c, b] = facc[kk, b, c]
            member_products(FP, FT, FO)
        for b in range(nb):
            if tmode == 2:
                for i in range(nx):
                    tx[b, i] = tall[b, i]
                for c in range(3):
                    table[b, c] = home[b, c] + fp[F_LOOP_UMV] * tall[b, nx + c]
            elif tmode == 3:
                for i in range(nx):
                    tx[b, i] = TT[i, b]
                for c in range(3):
                    table[b, c] = home[b, c] + fp[F_LOOP_UMV] * TT[nx + c, b]
            else:
                bi = 0 if tmode == 0 else b
                for c in range(3):
                    d3[c] = v_free[3 * b + c] / gain
                _matvec(TA[bi], tx[b], xn)
                _matvec(TB[bi], d3, tmp)
                for i in range(nx):
                    xn[i] = xn[i] + tmp[i]
                _matvec(TC[bi], xn, yy)
                _matvec(TD[bi], d3, ty)
                for i in range(nx):
                    tx[b, i] = xn[i]
                for c in range(3):
                    table[b, c] = home[b, c] + fp[F_LOOP_UMV] * (yy[c] + ty[c])
            if fmode > 0:
                if fmode == 2:
                    for i in range(nf):
                        fx[b, i] = FO[i, b]
                    for c in range(3):
                        table[b, c] = table[b, c] + FO[nf + c, b]
                else:
                    _matvec(FA[b], fx[b], fn)
                    for c in range(3):
                        d3[c] = facc[kk, b, c]
                    _matvec(FB[b], d3, ftmp)
                    for i in range(nf):
                        fx[b, i] = fn[i] + ftmp[i]
                    _matvec(FC[b], fx[b], yy)
                    for c in range(3):
                        table[b, c] = table[b, c] + yy[c]
        # -- sensors (BatchElectronics.read)
        for b in range(nb):
            for c in range(3):
                dd[3 * b + c] = table[b, c]
        sense_period(dd, kk, ip, fp, gb, ga, gz, gnoise, yv_ch, yu_ch, cl_ch)
        for b in range(nb):
            for c in range(3):
                ch = 3 * b + c
                y[b, c] = yv_ch[ch]
                last_clip[b, c] = cl_ch[ch]
                last_pz[b, c] = v_pz[ch]
                last_sat[b, c] = satv[ch]
                if rec:
                    sat_rec[b, k0 + kk, c] = satv[ch]
                if orec:                    # open-loop record: everything after the period
                    pz_rec[b, k0 + kk, c] = v_pz[ch]
                    tb[b, k0 + kk, c] = table[b, c]
                    yv[b, k0 + kk, c] = y[b, c]
                    yu_rec[b, k0 + kk, c] = yu_ch[ch]
                    cl_rec[b, k0 + kk, c] = cl_ch[ch]

def _f(x):
    return np.ascontiguousarray(x, dtype=float)


_EMPTY2 = np.zeros((0, 0))
_EMPTY3 = np.zeros((1, 0, 0))


def electronics_params(el):
    """The electronics' switches and scalars as the kernel's (ip, fp) arrays."""
    e = el.electronics
    ip = np.zeros(13, dtype=np.int64)
    fp = np.zeros(19)
    ip[I_QUANT], ip[I_SAT], ip[I_IMPLIED] = el._quant, el._sat, bool(el._dac_clip_implied)
    ip[I_LAG], ip[I_HYST], ip[I_CREEP] = el._lag.active, el._hyst, el._creep
    ip[I_DACN], ip[I_AMPN] = el._dac_noise is not None, el._amp_noise is not None
    ip[I_GFILT], ip[I_GNOISE] = el._gauge_filter is not None, el._gauge_noise is not None
    ip[I_CLIP], ip[I_ADC], ip[I_DELAY] = el._clip, el._adc, el._delay.n
    fp[F_CENTER], fp[F_LSB], fp[F_CLO], fp[F_CHI] = el._center, el._lsb, el._code_lo, el._code_hi
    fp[F_LO], fp[F_HI], fp[F_GAIN] = el._lo, el._hi, el._gain
    if el._lag.active:
        fp[F_LAG_1MA], fp[F_LAG_NA], fp[F_LAG_M] = 1.0 - el._lag._a, -el._lag._a, el._lag._m
    if el._hyst:
        fp[F_W0] = el._w0
    if el._creep:
        fp[F_CSCALE] = el._scale
    fp[F_RANGE], fp[F_UMV] = el._range, el._um_per_V
    if el._adc:
        fp[F_ADC_LSB], fp[F_ADC_LSB_UM], fp[F_ADC_LO], fp[F_ADC_HI] = (el._adc_lsb, el._adc_lsb_um, el._adc_lo,
                                                                      el._adc_hi)
    del e
    return ip, fp


def supported(stage, started: bool = True) -> bool:
    """True if the compiled loop can run ``stage``.

    That is: numba is installed, ``stage`` is a :class:`~nanosim.plant.batch.BatchTwinStage` built with
    ``compiled=True``, and (``started``) its gauge filter has
    seen its first sample (``stage.read()`` or one ``step``).
    """
    el = getattr(stage, "electronics", None)
    if not AVAILABLE or el is None or not getattr(stage, "compiled", False) or not hasattr(stage, "kernel_twin"):
        return False
    gf = el._gauge_filter
    return gf is None or gf._z is not None or not started


def twin_open_loop(stage, u_V: np.ndarray):
    """:meth:`BatchTwinStage.run` (open loop) of ``u_V`` ``(N, B, 3)`` in the compiled loop.

    ``stage`` must be :func:`supported` (its gauge filter started). Returns the record
    ``(piezo_V, saturated, table_um, reading_V, reading_um, clipped)``, each ``(B, N, 3)`` (members first).
    """
    nb = stage.n
    n = u_V.shape[0]
    pz, tb, yv, yu = (np.empty((nb, n, 3)) for _ in range(4))
    sat, cl = np.empty((nb, n, 3), dtype=bool), np.empty((nb, n, 3), dtype=bool)
    ctrl = (-1, np.zeros((1, 0, 0)), np.zeros((nb, 0)), 0, 0, False)
    _run(stage, ctrl, u_V, np.zeros((nb, 3)), True, (None, tb, None, sat), (True, pz, yv, yu, cl))
    return pz, sat, tb, yv, yu, cl


def twin_closed_loop(stage, ctrl, ref_V: np.ndarray, y_V: np.ndarray, record: bool):
    """Run the closed loop of a :class:`~nanosim.plant.batch.BatchTwinStage` and a controller bank.

    Parameters
    ----------
    stage : BatchTwinStage
        Advanced in place (every state, noise stream and ``last_*`` as after N ``step`` calls).
    ctrl : tuple (mode, matrix, xe, n_states, n_error, two_dof)
        The bank's arrays (:meth:`BatchController.kernel_arrays`); ``xe`` is updated in place.
    ref_V : ndarray, shape (N, B, n_error)
        Reference of every period in sensor volts.
    y_V : ndarray, shape (B, 3)
        Reading before the first period.
    record : bool
        Return the record (readings, table, commands before each period; saturation after).

    Returns
    -------
    y_V : ndarray, shape (B, 3)
        Reading after the last period.
    record : tuple of four (B, N, 3) arrays or None
        ``(y_V, table_um, u_V, saturated)``, members first (each member's rows contiguous).
    """
    nb = stage.n
    n = ref_V.shape[0]
    if record:
        recs = tuple(np.empty((nb, n, 3)) for _ in range(3)) + (np.empty((nb, n, 3), dtype=bool),)
    else:
        recs = (None, None, None, None)
    y = _run(stage, ctrl, ref_V, y_V, record, recs, (False, None, None, None, None))
    return y, (recs if record else None)


def _run(stage, ctrl, ref_V, y_V, record, recs, orecs):
    el = stage.electronics
    cmode, CM, xe, ns, ne, two_dof = ctrl
    nb = stage.n
    n = ref_V.shape[0]
    ref_V = _f(ref_V)
    y = _f(y_V).copy()
    e3 = np.empty((0, nb, 3))
    yv, tb, us, sat = (r if r is not None else e3 for r in recs)
    if sat is e3:
        sat = np.empty((0, nb, 3), dtype=bool)
    orec, pz, yv_o, yu, cl = orecs
    if orec:
        yv = yv_o
    else:
        pz, yu, cl = e3, e3, np.empty((0, nb, 3), dtype=bool)
    ip, fp = electronics_params(el)
    fp[F_LOOP_UMV] = C.SENSOR_UM_PER_V
    dbuf = el._delay._buf if el._delay.n else np.zeros((0, 3 * nb))
    lag_v = el._lag._v
    if el._hyst:
        pr, pw, pom, pp, z = _f(el._r), _f(el._w), _f(el._om), _f(el._pp), el._z   # z: (channels, operators)
    else:
        pr = pw = pom = np.zeros(0)
        pp = np.zeros(2)
        z = np.zeros((3 * nb, 0))
    if el._creep:
        csc, ca, cb, cx = _f(el._sc_col[:, 0]), _f(el._a_col[:, 0]), _f(el._b_col[:, 0]), el._x
    else:
        csc = ca = cb = np.zeros(0)
        cx = np.zeros((0, 3 * nb))
    tmode, TA, TB, TC, TD, TP, tx = stage.kernel_twin()
    fl = stage.floor
    if fl is not None and fl.active:
        fmode = 2 if fl._P is not None else 1
        FP = fl._P if fl._P is not None else _EMPTY3
        FA, FB, FC = (fl._Ad, fl._Bd, fl._Cd) if fmode == 1 else (_EMPTY3, _EMPTY3, _EMPTY3)
        fx = fl._x[:, :, 0].copy()
    else:
        fmode, FA, FB, FC, FP = 0, _EMPTY3, _EMPTY3, _EMPTY3, _EMPTY3
        fx = np.zeros((nb, 0))
    gf = el._gauge_filter
    if gf is not None:
        gb, ga, gz = _f(gf._b), _f(gf._a), gf._z
    else:
        gb = ga = np.zeros(1)
        gz = np.zeros((0, 3 * nb))
    table = stage.table_um.copy()
    last_pz, last_sat, last_clip = np.empty((nb, 3)), np.empty((nb, 3), dtype=bool), np.empty((nb, 3), dtype=bool)
    empty_noise = np.zeros((0, 0))
    sources = [src for src in (el._dac_noise, el._amp_noise, el._gauge_noise) if src is not None]
    k0 = 0
    while k0 < n:
        # at most the rows left in every noise chunk, so the rows are views of the chunks (no copy);
        # a period's numbers do not depend on where a call ends
        m = min([BLOCK, n - k0] + [src.rows_left() for src in sources])
        dacn = el._dac_noise.rows(m) if el._dac_noise is not None else empty_noise
        ampn = el._amp_noise.rows(m) if el._amp_noise is not None else empty_noise
        gn = el._gauge_noise.rows(m) if el._gauge_noise is not None else empty_noise
        facc = fl.take_accel(m) if fmode else np.zeros((0, nb, 3))
        _kernel(m, ref_V[k0:k0 + m], y, record, yv, tb, us, sat,
                cmode, CM, xe, ns, ne, two_dof,
                ip, fp, dbuf, dacn, ampn, lag_v, pr, pw, pom, pp, z, csc, ca, cb, cx,
                tmode, TA, TB, TC, TD, TP, tx, stage._home_um,
                fmode, FA, FB, FC, FP, fx, facc,
                gb, ga, gz, gn,
                table, last_pz, last_sat, last_clip, k0, orec, pz, yu, cl)
        k0 += m
    if fmode:
        fl._x[:, :, 0] = fx
    stage.kernel_twin_done(tx)
    if n:
        stage.table_um = table
        stage.last_piezo_V, stage.last_saturated, stage.last_clipped = last_pz, last_sat, last_clip
        for _ in range(n):
            stage.time_s += stage.dt_s
    return y


@njit(cache=True, error_model="numpy")
def flicker_cascade(e, gain, bz, ap, z):
    """:meth:`nanosim.plant.filters.FlickerShaper.run` on ``(N, channels)`` white samples, bit for bit
    (``FlickerShaper.step``'s arithmetic, sample by sample); ``z`` ``(sections, channels)`` is updated.
    """
    n, nch = e.shape
    ns = bz.shape[0]
    out = np.empty((n, nch))
    for i in range(n):
        for ch in range(nch):
            y = gain * e[i, ch]
            for k in range(ns):
                o = z[k, ch] + y
                z[k, ch] = y * (-bz[k]) - o * (-ap[k])
                y = o
            out[i, ch] = y
    return out

