"""The per-sample closed loop of :func:`.engine.simulate` fused into one numba-compiled loop.

:func:`run_block` executes, for samples ``k0 .. k1-1``, exactly the floating-point operations of
``PlantSimulator.measure`` -> ``Decoupler.step`` -> ``FeedbackLoop/FeedforwardLoop.step`` ->
``PlantSimulator.advance``, in the same order, over arrays taken from those very objects (see
:mod:`.fastsim`). Matrix-vector products use ``np.dot`` as the objects do: numba calls the same
BLAS ``gemv`` kernel as numpy, element-wise arithmetic is not contracted (no ``fastmath``), so
the result is bit-identical to the object path on the machines we tested.

Imported only when numba is available (``fastsim.available()``); the core never requires it.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _sos(b0, b1, b2, a1, a2, z, u):  # type: ignore[no-untyped-def]
    """SosFilter.step in place on ``u`` (channels,): transposed direct form II per section."""
    for i in range(b0.shape[0]):
        for c in range(u.shape[0]):
            x = u[c]
            y = b0[i, c] * x + z[i, 0, c]
            z[i, 0, c] = b1[i, c] * x - a1[i, c] * y + z[i, 1, c]
            z[i, 1, c] = b2[i, c] * x - a2[i, c] * y
            u[c] = y


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _clip(f, limit):  # type: ignore[no-untyped-def]
    """Allocator.clip in place; returns the number of clipped actuators."""
    n = 0
    for j in range(f.shape[0]):
        if abs(f[j]) > limit:
            n += 1
    if n:
        for j in range(f.shape[0]):
            if f[j] > limit:
                f[j] = limit
            elif f[j] < -limit:
                f[j] = -limit
    return n


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _finite(v):  # type: ignore[no-untyped-def]
    # a plain loop with an early exit, as numba's nopython mode compiles it best (not all()
    # over a generator)
    for j in range(v.shape[0]):  # noqa: SIM110
        if not np.isfinite(v[j]):
            return False
    return True


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def sosfilt_block(s, x, zf, y):  # type: ignore[no-untyped-def]
    """:func:`.sosfilter.sosfilt` into ``y`` (K, channels): sections ``s`` (n, 6) over ``x``
    (K, channels), states ``zf`` (n, 2, channels) advanced in place; the same expressions in
    the same order."""
    for c in range(x.shape[1]):
        for k in range(x.shape[0]):
            y[k, c] = x[k, c]
        for i in range(s.shape[0]):
            b0, b1, b2, a1, a2 = s[i, 0], s[i, 1], s[i, 2], s[i, 4], s[i, 5]
            z0, z1 = zf[i, 0, c], zf[i, 1, c]
            for k in range(x.shape[0]):
                v = y[k, c]
                w = b0 * v + z0
                z0 = b1 * v - a1 * w + z1
                z1 = b2 * v - a2 * w
                y[k, c] = w
            zf[i, 0, c], zf[i, 1, c] = z0, z1


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def run_block(k0, k1, plant, geo, ext, dec, ctl, fade, alloc, ground, dist, noise, excite,  # type: ignore[no-untyped-def]
              out):
    """Run samples ``k0 <= k < k1``; returns ``k1``, or the first sample with a non-finite
    value (the caller then reruns the object path, which owns the fault handling).

    Parameters (tuples of arrays, states updated in place; built by :mod:`.fastsim`)
    ----------
    plant : (A, B, C, chan, x, y, ax, bu, u, truthv, chv)
    geo, ext : (b0, b1, b2, a1, a2, z) of the geophone and extension filters
    dec : (starts (nb+1,), pinvs tuple, buffers tuple, vext)
    ctl : (b0, b1, b2, a1, a2, z, saved, axes, pinv, bmat, ubuf, fbuf: tuples per controller;
           limit (nc,), body (nc,), stage (nc,), wbuf (nc, dof))
    fade : (n (nc,), k (nc,), on (nc,)) integer arrays
    alloc : (pinvs tuple, limits (N,), forces tuple, totals (N, dof), counters (2,))
    ground, dist, noise : (m, dof), (m, N*dof), (m, n_ch) rows of samples k0..k1-1
    excite : (m, N*dof) excitation wrenches added after the controllers' (m x 0: none)
    out : (truth (K, N+1, dof), raw (K, n_ch), vel (K, N+1, dof), wrench (nc, K, dof),
           applied (K, n_act))
    """
    a_m, b_m, c_m, chan, x, y, ax, bu, u, truthv, chv = plant
    gb0, gb1, gb2, ga1, ga2, gz = geo
    eb0, eb1, eb2, ea1, ea2, ez = ext
    starts, dpinv, dbuf, vext = dec
    (cb0, cb1, cb2, ca1, ca2, cz, csaved, caxes, cpinv, cbm, cub, cfb,
     climit, cbody, cstage, wbuf) = ctl
    fn, fk, fon = fade
    apinv, alimit, aforce, totals, counters = alloc
    o_truth, o_raw, o_vel, o_wrench, o_applied = out
    dof = ground.shape[1]
    nst = totals.shape[0]
    nch = chv.shape[0]
    has_noise = noise.shape[1] == nch
    has_excite = excite.shape[1] == nst * dof
    nc = climit.shape[0]
    for k in range(k0, k1):
        r = k - k0
        # --- PlantSimulator.truth / measure
        np.dot(c_m, x, y)
        for j in range(dof):
            truthv[j] = ground[r, j]
        for j in range(y.shape[0]):
            truthv[dof + j] = y[j]
        for b in range(nst + 1):
            for j in range(dof):
                o_truth[k, b, j] = truthv[b * dof + j]
        np.dot(chan, truthv, chv)
        _sos(gb0, gb1, gb2, ga1, ga2, gz, chv)
        if has_noise:
            for j in range(nch):
                chv[j] += noise[r, j]
        o_raw[k] = chv
        if not _finite(chv):
            return k
        # --- Decoupler.step
        vext[:] = chv
        _sos(eb0, eb1, eb2, ea1, ea2, ez, vext)
        for b in range(starts.shape[0] - 1):
            buf = dbuf[b]
            for j in range(buf.shape[0]):
                buf[j] = vext[starts[b] + j]
            np.dot(dpinv[b], buf, o_vel[k, b])
        # --- controllers (Fader, filters, allocation, anti-windup)
        for c in range(nc):
            if fn[c] == 0:
                g = 1.0 if fon[c] else 0.0
            else:
                if fon[c] and fk[c] < fn[c]:
                    fk[c] += 1
                elif not fon[c] and fk[c] > 0:
                    fk[c] -= 1
                g = fk[c] / fn[c]
            w = wbuf[c]
            w[:] = 0.0
            xin = o_vel[k, cbody[c]]
            if not _finite(xin):
                return k
            z = cz[c]
            csaved[c][:] = z
            ub = cub[c]
            axes = caxes[c]
            for j in range(axes.shape[0]):
                ub[j] = xin[axes[j]]
            _sos(cb0[c], cb1[c], cb2[c], ca1[c], ca2[c], z, ub)
            for j in range(axes.shape[0]):
                w[axes[j]] = -g * ub[j]
            if g != 0.0:
                f = cfb[c]
                np.dot(cpinv[c], w, f)
                if _clip(f, climit[c]):
                    z[:] = csaved[c]
                    np.dot(cbm[c], f, w)
            o_wrench[c, k] = w
            if not _finite(w):
                return k
        # --- PlantSimulator.advance
        totals[:] = 0.0
        for c in range(nc):
            for j in range(dof):
                totals[cstage[c], j] += wbuf[c, j]
        if has_excite:
            for i in range(nst):
                for j in range(dof):
                    totals[i, j] += excite[r, i * dof + j]
        for j in range(dof):
            u[j] = ground[r, j]
        pos = dof
        for i in range(nst):
            f = aforce[i]
            np.dot(apinv[i], totals[i], f)
            counters[1] += _clip(f, alimit[i])
            for j in range(f.shape[0]):
                u[pos + j] = f[j]
            pos += f.shape[0]
        for j in range(pos - dof):
            o_applied[k, j] = u[dof + j]
        for j in range(dist.shape[1]):
            u[pos + j] = dist[r, j]
        np.dot(a_m, x, ax)
        np.dot(b_m, u, bu)
        for j in range(x.shape[0]):
            x[j] = ax[j] + bu[j]
    return k1


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def plant_sample(mats, x, work, geo, pinvs, limits, counters, wrench, stage, excite,  # type: ignore[no-untyped-def]
                 g_rows, d_rows, n_rows, r, rn, applied):
    """``PlantSimulator.advance`` of the sample at input row ``r`` (skipped if negative), then
    ``truth`` and ``measure`` of the sample at row ``rn`` (skipped if negative); returns the
    number of non-finite inputs (each skipped as the object skips it).

    ``mats``: (A, B, C, chan); ``x`` the plant's state; ``work`` the scratch, laid out
    ``y | ax | bu | u | truth (N+1)*dof | readings n_ch | totals N*dof | forces n_act``;
    ``geo`` the geophone filter's (b0, b1, b2, a1, a2, z); ``pinvs``, ``limits`` (N,) the
    allocators'; ``counters[1]`` the saturations; ``wrench`` (nc, dof) the controllers' in
    summation order, ``stage`` (nc,) their stage rows; ``excite`` (N, dof; 0 x 0: none);
    ``g_rows``, ``d_rows``, ``n_rows``: ground (m, dof), table wrenches (m, N*dof), geophone
    noise (m, n_ch or 0) of the drawn samples; ``applied`` (n_act,) the forces applied."""
    a_m, b_m, c_m, chan = mats
    gb0, gb1, gb2, ga1, ga2, gz = geo
    dof = g_rows.shape[1]
    nst = limits.shape[0]
    nx = x.shape[0]
    n_out = c_m.shape[0]
    n_in = b_m.shape[1]
    nch = chan.shape[0]
    o_ax = n_out
    o_bu = o_ax + nx
    o_u = o_bu + nx
    o_t = o_u + n_in
    o_c = o_t + (nst + 1) * dof
    o_tot = o_c + nch
    o_f = o_tot + nst * dof
    y, ax, bu, u = work[:n_out], work[o_ax:o_bu], work[o_bu:o_u], work[o_u:o_t]
    truthv, chv = work[o_t:o_c], work[o_c:o_tot]
    totals = work[o_tot:o_f].reshape(nst, dof)
    bad = 0
    if r >= 0:
        totals[:] = 0.0
        for c in range(wrench.shape[0]):
            if not _finite(wrench[c]):
                bad += 1
                continue
            for j in range(dof):
                totals[stage[c], j] += wrench[c, j]
        if excite.shape[0] == nst:
            ok = True
            for i in range(nst):
                ok = ok and _finite(excite[i])
            if ok:
                for i in range(nst):
                    for j in range(dof):
                        totals[i, j] += excite[i, j]
            else:
                bad += 1
        for j in range(dof):
            u[j] = g_rows[r, j]
        pos = dof
        o = o_f
        for i in range(nst):
            n_act = pinvs[i].shape[0]
            f = work[o:o + n_act]
            np.dot(pinvs[i], totals[i], f)
            counters[1] += _clip(f, limits[i])
            for j in range(n_act):
                u[pos + j] = f[j]
            pos += n_act
            o += n_act
        for j in range(pos - dof):
            applied[j] = u[dof + j]
        for j in range(d_rows.shape[1]):
            u[pos + j] = d_rows[r, j]
        np.dot(a_m, x, ax)
        np.dot(b_m, u, bu)
        for j in range(nx):
            x[j] = ax[j] + bu[j]
    if rn >= 0:
        np.dot(c_m, x, y)
        for j in range(dof):
            truthv[j] = g_rows[rn, j]
        for j in range(n_out):
            truthv[dof + j] = y[j]
        np.dot(chan, truthv, chv)
        _sos(gb0, gb1, gb2, ga1, ga2, gz, chv)
        if n_rows.shape[1] == nch:
            for j in range(nch):
                chv[j] += n_rows[rn, j]
    return bad


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def decouple_sample(ext, starts, pinvs, vext, raw, out):  # type: ignore[no-untyped-def]
    """``Decoupler.step`` of one sample whose readings ``raw`` (n_ch,) are all finite: the
    extension filter ``ext`` (b0, b1, b2, a1, a2, z) into ``vext``, then each body's
    ``pinvs[b]`` times its channels ``starts[b]:starts[b+1]`` into ``out[b]``; returns False
    (nothing done) if a reading is not finite."""
    if not _finite(raw):
        return False
    eb0, eb1, eb2, ea1, ea2, ez = ext
    vext[:] = raw
    _sos(eb0, eb1, eb2, ea1, ea2, ez, vext)
    for b in range(starts.shape[0] - 1):
        np.dot(pinvs[b], vext[starts[b]:starts[b + 1]], out[b])
    return True


#: :func:`control_sample`'s answers: the wrench is in ``w`` (no actuator can be at its limit),
#: the twist was not finite (nothing changed), or the caller must allocate (one may be).
CONTROL_DONE, CONTROL_NONFINITE, CONTROL_ALLOCATE = 0, 1, 2


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def control_sample(sos, saved, axes, ub, x, g, safe, w):  # type: ignore[no-untyped-def]
    """``_Loop.step`` of one twist ``x`` (dof,) at fader gain ``g`` up to the allocation: the
    filter states ``sos`` (b0, b1, b2, a1, a2, z) saved into ``saved``, the axes' inputs
    ``x[axes]`` filtered in ``ub``, ``w = -g * ub`` on those axes and zero elsewhere. Returns
    :data:`CONTROL_DONE`, :data:`CONTROL_NONFINITE` (states untouched) or
    :data:`CONTROL_ALLOCATE` (a component beyond ``safe``, the largest that saturates no
    actuator, and ``g`` not zero: the object's allocation and anti-windup follow)."""
    if not _finite(x):
        return CONTROL_NONFINITE
    b0, b1, b2, a1, a2, z = sos
    saved[:] = z
    for j in range(axes.shape[0]):
        ub[j] = x[axes[j]]
    _sos(b0, b1, b2, a1, a2, z, ub)
    w[:] = 0.0
    big = False
    for j in range(axes.shape[0]):
        v = -g * ub[j]
        w[axes[j]] = v
        if abs(v) > safe:
            big = True
    return CONTROL_ALLOCATE if big and g != 0.0 else CONTROL_DONE
