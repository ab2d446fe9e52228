"""Sensor-decoupling node: raw geophone channels -> one twist per body.

Subscribes to ``/dcsms/sensors/raw`` (``sensor_msgs/JointState``, ``velocity`` m/s), runs
:class:`~dcsms_ros.core.decoupling.Decoupler` once per sample (with numba compiled, the same
numbers: :mod:`dcsms_ros.core.compileddecoupler`) and publishes
``/dcsms/velocity/<body>`` (``geometry_msgs/TwistStamped``, frame_id = body) with the sample's
stamp; both sides as serialized CDR (:mod:`dcsms_ros.cdr`). A repeated stamp (lockstep
retransmission) is answered from the cache without stepping the filters again; an older stamp
is ignored (:class:`~dcsms_ros.protocols.responder.Answerer`). In real time the filters step
through every queued sample (:func:`~dcsms_ros.ros.qos.every_sample_sub`) and only the newest
is answered; a sample missing from the stream (lost) is stepped with the previous reading,
up to an input timeout's worth, so the filters keep the plant's time base (``held_samples``).
Channels are matched by name, so a publisher may send them in any order; a missing channel
reads NaN, which the core turns into a zero twist for that body (counted).
"""

from __future__ import annotations

from itertools import repeat
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import JointState

from dcsms_ros.cdr import TWIST_STAMPED, JointStateReader, StampedWriter
from dcsms_ros.core import topics
from dcsms_ros.core.compileddecoupler import decoupler
from dcsms_ros.nodes import recorder_part
from dcsms_ros.protocols.responder import skip_free_ns, skipped
from dcsms_ros.ros import qos
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.guard import MAX_VELOCITY_MPS, InputGuard
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import SamplePublisher
from dcsms_ros.ros.logthrottle import Throttled
from dcsms_ros.ros.params import (
    SELECTORS,
    NodeConfig,
    answerer,
    declare_observed,
    declare_schedule,
)
from dcsms_ros.ros.readiness import DECOUPLING, ReadyAnnouncer
from dcsms_ros.ros.reports import Reports, Status
from dcsms_ros.ros.runtime import main_for


class SensorDecouplingNode(GraphNode, Hosted):
    """ROS adapter around :class:`~dcsms_ros.core.decoupling.Decoupler`."""

    hot: HotPath  # every instance has one (Hosted declares it optional)

    def __init__(self, node_name: str = "sensor_decoupling", **kwargs: Any) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.params = NodeConfig(self, SELECTORS["sensor_decoupling"])
        cfg = self.params.cfg
        lockstep = declare_schedule(self) == "lockstep"
        self.observed = declare_observed(self)
        self.dec = decoupler(cfg)
        self.guard = InputGuard(self, "raw sensor channels", MAX_VELOCITY_MPS)
        self.dof = cfg.plant.dof
        self.bodies = topics.body_names(cfg.plant.num_stages)
        self.names = list(self.dec.channel_names)
        self.reader = JointStateReader("velocity")
        self._own: tuple[str, ...] | None = None  # the reader's tuple of our own names
        self._index: dict[tuple[str, ...], np.ndarray] = {}
        self.writers = [StampedWriter(TWIST_STAMPED, b, self.dof) for b in self.bodies]
        # lockstep: transient local, so mode_switch's trip checker gets every sample from 0
        self.hot = HotPath(self)  # _on_raw runs on the hot thread, under the path's lock
        self.pubs = [self.hot.publisher(TwistStamped, topics.LOCAL.velocity(b),
                                        qos.stream_pub(lockstep, durable=True))
                     for b in self.bodies]
        self.reports = Reports(self, self.hot)
        self.hot.subscribe(JointState, topics.LOCAL.sensors_raw, self._on_raw,
                           qos.every_sample_sub(lockstep), raw=True,
                           flush=None if lockstep else self._answer)
        # lockstep: the first sample is answered only once every reader is matched
        self.answers = answerer(self, self._publish, lockstep, self.pubs, self.observed)
        self.samples = 0
        self.held_samples = 0  # missing samples stepped with the previous reading
        self.bad_messages = 0
        self.published = 0  # answers sent (a repeat too); real time: fewer than samples
        self._rate = cfg.plant.rate_hz
        self._gap_ns = skip_free_ns(self._rate)
        self._hold_cap = round(cfg.control.input_timeout_s * cfg.plant.rate_hz)
        self._last_raw: np.ndarray | None = None
        self._pending: tuple[int, np.ndarray] | None = None  # real time: the newest answer
        self.lockstep = lockstep
        self._log_nonfinite = Throttled(self.get_logger(), 2.0)
        self.housekeeping(1.0, self._report)
        # real time: the plant starts once DDS matched this node's ends (lockstep retransmits)
        self.ready = (None if lockstep else
                      ReadyAnnouncer(self, self.hot, DECOUPLING, self.observed))
        self.hot.start()

    def _channels(self, key: tuple[str, ...], v: np.ndarray) -> np.ndarray:
        """Channel velocities in the decoupler's order (NaN where missing); ``key``: the
        message's names as the reader returns them (one tuple object per layout)."""
        if key is self._own and v.shape[0] == len(self.names):
            return v  # the plant's own names and order: the common, cheap case
        if list(key) == self.names and v.shape[0] == len(self.names):
            self._own = key
            return v
        idx = self._index.get(key)
        if idx is None:
            pos = {n: i for i, n in enumerate(key)}
            idx = np.array([pos.get(n, -1) for n in self.names])
            self._index[key] = idx
            if (idx < 0).any() or len(key) != v.shape[0]:
                lacks = [n for n, i in zip(self.names, idx, strict=True) if i < 0]
                self.get_logger().warning(f"raw message lacks channels {lacks} or "
                                          f"has {v.shape[0]} values for {len(key)} names")
        if len(key) != v.shape[0]:
            self.bad_messages += 1
            return np.full(len(self.names), np.nan)
        return np.where(idx >= 0, v[np.maximum(idx, 0)], np.nan)

    def _on_raw(self, buf: bytes) -> None:
        ns, names, v = self.reader.read(buf)
        # implausible channels are counted on arrival and read NaN (that body's twist is zero)
        raw = self.guard.clean_each(self._channels(names, v), np.nan)
        last = self.answers.last_ns
        if not self.answers.due(ns):
            return
        # not called for the usual gap, where it is 0
        if self._last_raw is not None and ns - last > self._gap_ns:
            gap = skipped(last, ns, self._rate, self._hold_cap)
            for _ in range(gap):
                self.dec.step(self._last_raw)
            self.held_samples += gap
        tw = self.dec.step(raw)
        self._last_raw = raw
        self.samples += 1
        if self.lockstep:
            self.answers.reply(ns, self._encode(ns, tw))
        else:  # the newest of this wake-up's samples is answered by _answer
            self.answers.advance(ns)
            self._pending = (ns, tw)
        if self.dec.nonfinite:
            self._log_nonfinite(lambda: f"non-finite sensor channels: {self.dec.nonfinite} "
                                        f"body samples zeroed")

    def _encode(self, ns: int, tw: np.ndarray) -> list[bytes]:
        rows = tw.tolist()  # one numpy call, not a row view and a scalar per body
        # map, not a comprehension: no frame of its own (Python 3.11)
        return list(map(StampedWriter.encode, self.writers, repeat(ns), rows))

    def _answer(self) -> None:
        """Real time: publish the answer to the newest sample read at this wake-up."""
        if self._pending is not None:
            ns, tw = self._pending
            self._pending = None
            self._publish(self.answers.store(ns, self._encode(ns, tw)))

    def _publish(self, msgs: list[bytes]) -> None:
        self.published += 1
        for pub, m in zip(self.pubs, msgs, strict=True):
            pub.publish(m)

    def _report(self) -> None:
        level = DiagnosticStatus.WARN if self.dec.nonfinite or self.bad_messages else \
            DiagnosticStatus.OK
        self.reports.publish(self.answers.last_ns, [Status(level, "running", {
            "samples": self.samples, "held_samples": self.held_samples,
            "published": self.published,
            "repeats": self.answers.repeats,
            "out_of_order": self.answers.out_of_order,
            "nonfinite": self.dec.nonfinite, "bad_messages": self.bad_messages,
            "rejected_inputs": self.guard.rejected})])

    def final_reports(self) -> list[SamplePublisher]:
        """Publish the final counters; returns the publishers whose readers should
        acknowledge before the node goes (a clean exit loses nothing)."""
        self._report()
        return [*self.pubs, self.reports.pub]


main = main_for(SensorDecouplingNode, attach=recorder_part.attach)

if __name__ == "__main__":
    main()
