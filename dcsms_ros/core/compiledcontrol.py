"""The controllers' per-sample work in one numba-compiled call, the same numbers.

:meth:`_Loop.step <.controllers.FeedbackLoop.step>` filters a few floats in Python, ~3 us a
sample for table1's one axis and ~5.5 us for a 6dof stage; the composed graph runs three of
them in its one thread every sample, one process per node one in each controller's. The
compiled classes run the same operations in the same order in
:func:`.fastloop.control_sample` (the controller part of the batch engine's fused loop): the
fader's step, the saved states, the filter, the wrench. A non-finite twist, a twist of the
wrong shape and a wrench that may saturate an actuator (the allocation and anti-windup) take
the object's own code on the same states, so every answer and counter is the object's.

:func:`controller` builds one when asked and numba is there (:func:`.fastsim.available`),
else a :class:`.FeedbackLoop` / :class:`.FeedforwardLoop`; the kernel is compiled (or loaded
from numba's cache) when the first one is built. The controller nodes ask for it in a composed
process only: there numba is loaded already (the plant's) and a step saves ~1 us (table1) to
3 us (6dof) of the one driver thread, the composed lockstep graph ran 9-32 % faster (same-run
pairs); in a process of its own a controller spends ~100 us of CPU a sample, mostly waking up,
and importing numba made the graph connect 0.6-0.9 s later (1.7-2.0 s -> 2.6 s, 3 pairs).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import (
    Array,
    FeedbackLoop,
    FeedforwardLoop,
    Kinds,
    _Loop,
    make_controller,
)
from dcsms_ros.core.fastsim import available


class _CompiledStep(_Loop):
    """:meth:`step` through :func:`.fastloop.control_sample` on the loop's own arrays."""

    def _views(self) -> None:
        from dcsms_ros.core import fastloop  # noqa: PLC0415 - optional: numba

        super()._views()  # also after unpickling: the kernel's arrays are the copy's
        self._kernel = fastloop.control_sample
        self._done, self._nonfinite = fastloop.CONTROL_DONE, fastloop.CONTROL_NONFINITE
        self._sos = tuple(self.filter.arrays)
        self._k_axes = self.axes.astype(np.int64)
        self._ub = np.zeros(self._k_axes.shape[0])
        self._w = np.zeros(self.dof)
        self._x = np.zeros(self.dof)  # step_floats's input
        self._safe = float(self.allocator.safe_wrench)
        z, before = self._sos[5], self._saved
        kept = z.copy(), before.copy()  # compile (or load) now, not at the first sample
        self._kernel(self._sos, before, self._k_axes, self._ub, np.zeros(self.dof), 0.0,
                     self._safe, self._w)
        np.copyto(z, kept[0])
        np.copyto(before, kept[1])

    def __getstate__(self) -> dict[str, object]:
        skip = ("_kernel", "_sos")  # a function, and views rebuilt by _views
        return {k: v for k, v in super().__getstate__().items() if k not in skip}

    def step(self, twist: ArrayLike) -> Array:
        """As :meth:`.FeedbackLoop.step` (a new array, the same values and counters)."""
        x = np.asarray(twist, dtype=np.float64)
        if x.shape != self._w.shape or not x.flags.c_contiguous:
            # the object's floats (its step would come back here through step_floats)
            return np.array(super().step_floats(x.tolist()))
        w = self._run(x)
        return w.copy() if w is self._w else w

    def step_floats(self, x: Sequence[float]) -> list[float]:
        """As :meth:`.FeedbackLoop.step_floats`, through the kernel (a node's sample: the floats
        into the loop's own input array, no array made or copied on the usual path)."""
        xs = self._x
        if len(x) != xs.shape[0]:
            return super().step_floats(x)  # the object's floats decide (as :meth:`step`)
        xs[:] = x
        return self._run(xs).tolist()

    def _run(self, x: Array) -> Array:
        """The kernel on twist ``x`` (dof,): the wrench, the loop's own output array on the
        usual sample (the caller copies or converts it), else a new one."""
        w = self._w
        got = self._kernel(self._sos, self._saved, self._k_axes, self._ub, x,
                           self.fader.step(), self._safe, w)
        if got == self._done:
            self.last_saturated = 0
            return w
        if got == self._nonfinite:
            return self._rejected()
        self.last_saturated = 0
        return self._allocated(w.copy())


class CompiledFeedbackLoop(_CompiledStep, FeedbackLoop):
    """A :class:`.FeedbackLoop` whose :meth:`step` runs compiled."""


class CompiledFeedforwardLoop(_CompiledStep, FeedforwardLoop):
    """A :class:`.FeedforwardLoop` whose :meth:`step` runs compiled."""


#: The compiled controller classes, as :func:`.make_controller` takes them.
COMPILED: Kinds = (CompiledFeedbackLoop, CompiledFeedforwardLoop)


def controller(cfg: SystemConfig, controller_id: str, enabled: bool = False,
               compiled: bool = True) -> FeedbackLoop | FeedforwardLoop:
    """:func:`.make_controller` of the compiled classes when ``compiled`` and numba is there,
    else of the objects' (:meth:`.controllers.retuned` keeps the class)."""
    return make_controller(cfg, controller_id, enabled, COMPILED if compiled and available()
                           else (FeedbackLoop, FeedforwardLoop))


__all__ = ["COMPILED", "CompiledFeedbackLoop", "CompiledFeedforwardLoop", "controller"]
