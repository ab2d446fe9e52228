"""The closed loop that runs, as one discrete-time linear system.

:func:`loop_model` reads its coefficients from the very step objects :func:`.engine.simulate`
steps, in the engine's sample order: the exact ZOH plant at ``plant.rate_hz``
(:class:`.PlantSimulator`), the geophone filters and the channel matrix, the low-frequency
extension and ``pinv(S)`` per body (:class:`.Decoupler`), every controller's second-order
sections at full fader gain (:func:`.make_controller`), and allocation through each stage's
drive matrix (:class:`.Allocator`). Sample k: the geophones read the state x_k, the controllers
answer with the wrench of sample k, and that wrench is held over k -> k+1. Saturation and fault
handling are the only parts left out: the model is the loop while no actuator clips.

Inputs, grouped (``LoopModel.inputs``): ``ground`` twist (dof; m/s, rad/s), ``table`` wrench on
each stage at its reference point (N*dof; N, N*m), ``noise`` added to each geophone reading
(n_ch; m/s), ``excite`` wrench per stage added to the controllers' before allocation (N*dof),
``break`` (one per broken controller output, see :class:`Break`). Outputs: ``stage`` true twists
(N*dof), ``velocity`` decoupled twists of ground and stages ((N+1)*dof), ``force`` per actuator
(n_act; N) and ``return`` (the broken controller outputs, N or N*m).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.modes import ControllerId, Mode, controller_ids, enabled_controllers
from dcsms_ros.core.simulator import PlantSimulator, check_plant
from dcsms_ros.core.sosfilter import SosFilter, sos_state_space

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]


@dataclass(frozen=True)
class Break:
    """One opened controller output: ``controller`` id and ``axis`` (index into its stage's
    ``dof`` vector). The controller's value leaves as a ``return`` output; the loop goes on
    with a ``break`` input in its place."""

    controller: str
    axis: int


@dataclass(frozen=True)
class LoopModel:
    """``x[k+1] = a x[k] + b u[k]``, ``y[k] = c x[k] + d u[k]`` at sample period ``dt`` (s).

    ``inputs`` and ``outputs`` map group names to column / row slices (module docstring).
    """

    a: Array
    b: Array
    c: Array
    d: Array
    dt: float
    inputs: dict[str, slice]
    outputs: dict[str, slice]
    mode: Mode
    breaks: tuple[Break, ...] = ()
    #: per state: the part of the loop it belongs to (``plant``, ``geophones``, ``extension``
    #: or a controller id); empty when unknown
    parts: tuple[str, ...] = ()

    @property
    def nstates(self) -> int:
        return int(self.a.shape[0])

    @property
    def fs(self) -> float:
        """Sample rate, Hz."""
        return 1.0 / self.dt

    def select(self, inputs: str | Sequence[int] | slice, outputs: str | Sequence[int] | slice
               ) -> LoopModel:
        """The sub-system from some inputs to some outputs (group names or indices)."""
        i = self.inputs[inputs] if isinstance(inputs, str) else inputs
        o = self.outputs[outputs] if isinstance(outputs, str) else outputs
        b, c, d = self.b[:, i], self.c[o], self.d[o][:, i]
        return LoopModel(self.a, b, c, d, self.dt, {"u": slice(0, b.shape[1])},
                         {"y": slice(0, c.shape[0])}, self.mode, self.breaks, self.parts)


class _Builder:
    """Affine signal maps ``s = sx @ X + su @ U`` over the full state X and inputs U."""

    def __init__(self, nx: int, nu: int) -> None:
        self.a = np.zeros((nx, nx))
        self.b = np.zeros((nx, nu))
        self.nx, self.nu = nx, nu

    def zeros(self, m: int) -> tuple[Array, Array]:
        return np.zeros((m, self.nx)), np.zeros((m, self.nu))

    def filters(self, sos: Array, offset: int, sig: tuple[Array, Array]) -> tuple[Array, Array]:
        """Run each channel j of ``sig`` through its sections ``sos[j]`` (states from
        ``offset``, channel after channel); returns the output signal map."""
        sx, su = sig
        ox, ou = self.zeros(sx.shape[0])
        pos = offset
        for j in range(sx.shape[0]):
            fa, fb, fc, fd = sos_state_space(sos[j])
            n = fa.shape[0]
            s = slice(pos, pos + n)
            self.a[s, s] += fa
            self.a[s] += fb @ sx[j:j + 1]
            self.b[s] += fb @ su[j:j + 1]
            ox[j, s] = fc[0]
            ox[j] += fd[0, 0] * sx[j]
            ou[j] += fd[0, 0] * su[j]
            pos += n
        return ox, ou


def _filter_states(f: SosFilter) -> int:
    return 2 * f.sections * f.channels


def loop_model(cfg: SystemConfig, mode: Mode, breaks: Sequence[Break] = (),
               plant: SystemConfig | None = None) -> LoopModel:
    """The discrete closed loop of ``mode`` as the batch engine runs it (module docstring).

    Parameters
    ----------
    cfg : SystemConfig
    mode : Mode
        Its controllers are at full gain; the others contribute nothing.
    breaks : sequence of Break
        Controller outputs to open (loop gains, margins).
    plant : SystemConfig, optional
        The physical plant and its geophones when they differ from ``cfg`` (``simulate``'s
        ``plant``): the controllers and the decoupling's extension still come from ``cfg``.

    Returns
    -------
    LoopModel
        States: the plant's, then every filter's delays; states that stay zero whatever the
        input (the unused delay of a first-order section) are removed.
    """
    if plant is not None:
        check_plant(cfg, plant)
    sim = PlantSimulator(plant or cfg, seed=0, disturbances=False)
    dec = Decoupler(cfg)
    n, dof = cfg.plant.num_stages, cfg.plant.dof
    on = enabled_controllers(mode, n)
    ctrls = {cid: make_controller(cfg, cid, enabled=True) for cid in controller_ids(n)
             if cid in on}
    ctrls = {cid: c for cid, c in ctrls.items() if c.tfs}
    for br in breaks:
        if br.controller not in ctrls or br.axis not in ctrls[br.controller].tfs:
            raise ValueError(f"cannot break {br.controller} axis {br.axis}: not active in "
                             f"{mode.label}")
    dplant = sim.plant
    nxp = dplant.x.size
    geo, ext = sim.geophones.filter, dec.extension
    n_ch = len(sim.channels)
    n_act = sim.num_actuators
    offsets = [nxp, nxp + _filter_states(geo)]
    offsets.append(offsets[-1] + _filter_states(ext))
    for loop in ctrls.values():
        offsets.append(offsets[-1] + _filter_states(loop.filter))
    nx = offsets[-1]
    parts = (["plant"] * nxp + ["geophones"] * _filter_states(geo)
             + ["extension"] * _filter_states(ext))
    for cid, loop in ctrls.items():
        parts += [cid] * _filter_states(loop.filter)
    groups = {"ground": dof, "table": n * dof, "noise": n_ch, "excite": n * dof,
              "break": len(breaks)}
    inputs, pos = {}, 0
    for name, size in groups.items():
        inputs[name] = slice(pos, pos + size)
        pos += size
    bld = _Builder(nx, pos)
    # true twists [ground, stage 1..N] of sample k
    tx, tu = bld.zeros((n + 1) * dof)
    tx[dof:, :nxp] = dplant.ss.c
    tu[:dof, inputs["ground"]] = np.eye(dof)
    chan = sim.channel_matrix
    raw_x, raw_u = bld.filters(geo.coefficients(), offsets[0], (chan @ tx, chan @ tu))
    raw_u[:, inputs["noise"]] += np.eye(n_ch)
    ex_x, ex_u = bld.filters(ext.coefficients(), offsets[1], (raw_x, raw_u))
    vx, vu = bld.zeros((n + 1) * dof)
    for i, (sl, pinv) in enumerate(dec.blocks):
        vx[i * dof:(i + 1) * dof] = pinv @ ex_x[sl]
        vu[i * dof:(i + 1) * dof] = pinv @ ex_u[sl]
    # wrench totals per stage, the excitation first
    wx, wu = bld.zeros(n * dof)
    wu[:, inputs["excite"]] = np.eye(n * dof)
    rx, ru = bld.zeros(len(breaks))
    for j, (cid, loop) in enumerate(ctrls.items()):
        who = ControllerId.parse(cid)
        axes = loop.axes
        src = [who.sensed_body * dof + int(a) for a in axes]
        yx, yu = bld.filters(loop.filter.coefficients(), offsets[2 + j], (vx[src], vu[src]))
        stage = who.stage - 1
        for row, a in enumerate(axes):
            dst = stage * dof + int(a)
            hit = [k for k, br in enumerate(breaks) if (br.controller, br.axis) == (cid, a)]
            if hit:
                rx[hit[0]], ru[hit[0]] = -yx[row], -yu[row]
                wu[dst, inputs["break"].start + hit[0]] += 1.0
            else:
                wx[dst] -= yx[row]
                wu[dst] -= yu[row]
    fx, fu = bld.zeros(n_act)
    pos = 0
    for i, alloc in enumerate(sim.allocators):
        rows = slice(pos, pos + alloc.n_act)
        fx[rows] = alloc.pinv @ wx[i * dof:(i + 1) * dof]
        fu[rows] = alloc.pinv @ wu[i * dof:(i + 1) * dof]
        pos += alloc.n_act
    # plant input [ground | actuator forces | table wrenches], held over k -> k+1
    ux, uu = bld.zeros(dof + n_act + n * dof)
    ux[dof:dof + n_act], uu[dof:dof + n_act] = fx, fu
    uu[:dof, inputs["ground"]] = np.eye(dof)
    uu[dof + n_act:, inputs["table"]] = np.eye(n * dof)
    bld.a[:nxp, :nxp] += dplant.ss.a
    bld.a[:nxp] += dplant.ss.b @ ux
    bld.b[:nxp] += dplant.ss.b @ uu
    outs = [("stage", tx[dof:], tu[dof:]), ("velocity", vx, vu), ("force", fx, fu),
            ("return", rx, ru)]
    c = np.vstack([o[1] for o in outs])
    d = np.vstack([o[2] for o in outs])
    outputs, pos = {}, 0
    for name, ox, _ in outs:
        outputs[name] = slice(pos, pos + ox.shape[0])
        pos += ox.shape[0]
    keep = _live(bld.a, bld.b)
    return LoopModel(bld.a[np.ix_(keep, keep)], bld.b[keep], c[:, keep], d, cfg.plant.dt,
                     inputs, outputs, mode, tuple(breaks),
                     tuple(p for p, k in zip(parts, keep, strict=True) if k))


def _live(a: Array, b: Array) -> NDArray[np.bool_]:
    """States that can leave zero: drops those no input reaches and only such states feed
    (the second delay of a first-order section, a pass-through section's delays)."""
    keep = np.ones(a.shape[0], dtype=bool)
    while True:
        dead = keep & ~np.any(b != 0.0, axis=1) & ~np.any(a[:, keep] != 0.0, axis=1)
        if not dead.any():
            return keep
        keep &= ~dead


def poles(model: LoopModel) -> CArray:
    """Eigenvalues z of ``a`` (the discrete poles)."""
    return np.asarray(np.linalg.eigvals(model.a), dtype=np.complex128)


def pole_parts(model: LoopModel) -> tuple[CArray, list[str]]:
    """Poles z and, for each, the part of the loop (``LoopModel.parts``) that participates
    most in it (participation factors ``|w_ik v_ki|``, independent of state scaling)."""
    z, vl, vr = scipy.linalg.eig(model.a, left=True, right=True)
    part = np.abs(vl.conj() * vr)
    part /= np.maximum(part.sum(axis=0, keepdims=True), 1e-300)
    names = sorted(set(model.parts))
    share = np.array([[part[[k for k, p in enumerate(model.parts) if p == n], i].sum()
                       for n in names] for i in range(z.size)])
    return (np.asarray(z, dtype=np.complex128),
            [names[int(np.argmax(row))] if names else "" for row in share])


def s_plane(z: CArray, fs: float) -> CArray:
    """``s = fs ln z`` (rad/s) of discrete poles; a pole at z = 0 maps to ``-inf``."""
    zz = np.asarray(z, dtype=np.complex128)
    out = np.full(zz.shape, -np.inf + 0j, dtype=np.complex128)
    nz = zz != 0
    out[nz] = fs * np.log(zz[nz])
    return out


class Response:
    """Frequency response of a :class:`LoopModel` at any frequencies.

    ``__call__(f_hz)`` returns ``c (zI - a)^-1 b + d`` at ``z = exp(j 2 pi f dt)``, shape
    (F, n_outputs, n_inputs). The complex Schur form ``a = Q T Q^H`` is computed once; every
    call then solves the triangular systems of all frequencies together, by back substitution
    on the inputs' side or forward substitution on the outputs' side, whichever is narrower.
    """

    def __init__(self, model: LoopModel) -> None:
        # balance first: the states span ~12 decades (metres to newtons), and the Schur form's
        # normwise rounding would otherwise cost the small entries their accuracy (1e-4 of
        # the response at low frequency instead of 1e-11)
        a, d = scipy.linalg.matrix_balance(model.a, permute=False, separate=True)
        scale = d[0]
        t, q = scipy.linalg.schur(a.astype(np.complex128), output="complex")
        self._t = t
        self._b = q.conj().T @ (model.b / scale[:, None])
        self._c = (model.c * scale[None, :]) @ q
        self._d = model.d
        self._dt = model.dt

    def __call__(self, f_hz: Sequence[float] | Array) -> CArray:
        f = np.asarray(f_hz, dtype=np.float64).ravel()
        z = np.exp(2j * np.pi * f * self._dt)
        t, n = self._t, self._t.shape[0]
        out = np.empty((f.size, self._c.shape[0], self._b.shape[1]), dtype=np.complex128)
        for k0 in range(0, f.size, 512):
            zk = z[k0:k0 + 512]
            piv = zk[:, None] - np.diag(t)[None, :]  # (F, n): the diagonal of zI - T
            if self._c.shape[0] <= self._b.shape[1]:
                # Y (zI - T) = C Q, column by column; then H = Y Q^H B
                y = np.zeros((zk.size, self._c.shape[0], n), dtype=np.complex128)
                for j in range(n):
                    y[:, :, j] = (self._c[None, :, j] + y[:, :, :j] @ t[:j, j]) / piv[:, j:j + 1]
                out[k0:k0 + zk.size] = y @ self._b + self._d
            else:
                # (zI - T) X = Q^H B, row by row from the bottom; then H = C Q X
                x = np.zeros((zk.size, n, self._b.shape[1]), dtype=np.complex128)
                for i in range(n - 1, -1, -1):
                    acc = self._b[None, i, :] + np.einsum("j,fjr->fr", t[i, i + 1:],
                                                          x[:, i + 1:, :])
                    x[:, i, :] = acc / piv[:, i:i + 1]
                out[k0:k0 + zk.size] = self._c @ x + self._d
        return out


def freq_response(model: LoopModel, f_hz: Sequence[float] | Array) -> CArray:
    """``c (zI - a)^-1 b + d`` at ``z = exp(j 2 pi f dt)`` (see :class:`Response`).

    Returns
    -------
    ndarray of complex, shape (F, n_outputs, n_inputs)
    """
    return Response(model)(f_hz)


__all__ = ["Break", "LoopModel", "Response", "freq_response", "loop_model", "pole_parts", "poles",
           "s_plane"]
