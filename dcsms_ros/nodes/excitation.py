"""Excitation node ``excitation``: a known force on one stage for identification.

Publishes ``force/excitation`` (geometry_msgs/WrenchStamped, frame_id = the pushed stage, N and
N*m; names relative to the graph's namespace) for every sample of the plant: it answers each
``sensors/raw`` sample, stamped like it, as a controller answers its velocity (a repeated stamp
from the cache, :class:`~dcsms_ros.protocols.responder.Answerer`), so the plant (parameter
``excitation: true``) sums it with the controllers' wrenches before allocation and clipping and,
in lockstep, waits for it like for a controller (same timeout and absence rules; in real time a
stale excitation counts as zero after ``control.input_timeout_s``). Zero while inactive. The
signal of sample k is :class:`~dcsms_ros.core.excitation.Excitation` of the specifications
(``spec``, as ``dcsms sim --excite``) and ``disturbance.seed``, counted from the sample it was
started on: a run active from sample 0 adds exactly what ``dcsms sim --excite`` adds.

``~/enable`` (std_srvs/SetBool, ``<namespace>/excitation/enable``) starts (true) or stops
(false) it; parameter ``active`` starts it with the run. It is never active while the
instability trip holds the table: ``mode_switch`` publishes every change of that on
``supervisor/state`` (TRIPPED or LATCHED, with or without the supervisor), which stops the
excitation and refuses a start until the supervisor re-engages or the latch is reset.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool

from dcsms_ros.cdr import WRENCH_STAMPED, JointStateReader, StampedWriter
from dcsms_ros.core import topics
from dcsms_ros.core.excitation import Excitation, check_specs, parse_spec
from dcsms_ros.core.supervisor import TRIPPED_STATES
from dcsms_ros.errors import ConfigError
from dcsms_ros.nodes import recorder_part
from dcsms_ros.ros import qos
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import SamplePublisher
from dcsms_ros.ros.params import (
    NodeConfig,
    answerer,
    declare_local,
    declare_observed,
    declare_schedule,
)
from dcsms_ros.ros.readiness import ReadyAnnouncer
from dcsms_ros.ros.reports import Reports, Status
from dcsms_ros.ros.runtime import main_for


class ExcitationNode(GraphNode, Hosted):
    """ROS adapter around :class:`~dcsms_ros.core.excitation.Excitation`."""

    hot: HotPath  # every instance has one (Hosted declares it optional)

    def __init__(self, node_name: str = topics.EXCITATION_ID, **kwargs: Any) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.hot = HotPath(self)
        self.params = NodeConfig(self, lambda n: n == "disturbance.seed")
        cfg = self.params.cfg
        self.lockstep = declare_schedule(self) == "lockstep"
        texts = declare_local(self, "spec", ["stage1.z:white:1"], "Excitations as `dcsms sim "
                              "--excite` takes them, e.g. stage1.z:white:5 (one stage)")
        try:
            self.specs = [parse_spec(t) for t in texts]
            check_specs(cfg, self.specs)
        except ConfigError as exc:
            raise ConfigError(f"node {self.get_name()}: parameter 'spec': {exc}") from None
        if not self.specs:
            raise ConfigError(f"node {self.get_name()}: parameter 'spec' is empty")
        start = bool(declare_local(self, "active", False, "Start active with the run (as "
                                   "dcsms sim --excite); else start with ~/enable"))
        self.period_s = float(declare_local(self, "duration_s", 0.0, "Default period of "
                                            "sweeps and stepped sines; 0: 60 s [s]", lo=0.0,
                                            hi=1e9))
        self.observed = declare_observed(self)
        self.cfg = cfg
        self.rate = cfg.plant.rate_hz
        self.seed = cfg.disturbance.seed
        self.stage = self.specs[0].stage
        self.writer = StampedWriter(WRENCH_STAMPED, f"stage{self.stage}", cfg.plant.dof)
        self.reader = JointStateReader()
        self._zero = np.zeros(cfg.plant.dof)
        self.exc: Excitation | None = None
        self.k0 = 0  # sample the excitation was started on
        self._start_pending = start  # start on the first sample (lockstep: sample 0)
        self.tripped = False
        self.samples = 0
        self.names = topics.Names(self.get_namespace())
        self.pub = self.hot.publisher(WrenchStamped, topics.LOCAL.force(topics.EXCITATION_ID),
                                      qos.stream_pub(self.lockstep))
        self.answers = answerer(self, self.pub.publish, self.lockstep, [self.pub],
                                self.observed)
        self.reports = Reports(self, self.hot)
        self.hot.subscribe(JointState, topics.LOCAL.sensors_raw, self._on_sample,
                           qos.stream_sub(self.lockstep), raw=True)
        # a decision from a named topic, not from another node's diagnostics text
        self.create_subscription(String, topics.LOCAL.supervisor_state, self._on_state,
                                 qos.events())
        self.create_service(SetBool, "~/enable", self._on_enable)
        self.housekeeping(1.0, self._report)
        # real time: the plant starts once DDS matched this node's ends (lockstep retransmits)
        self.ready = (None if self.lockstep else
                      ReadyAnnouncer(self, self.hot, topics.EXCITATION_ID, self.observed))
        self.get_logger().info(f"excitation {', '.join(s.text for s in self.specs)} on "
                               f"{self.pub.topic_name}, {'active' if start else 'inactive'}")
        self.hot.start()

    @property
    def active(self) -> bool:
        return self.exc is not None or self._start_pending

    def _on_sample(self, buf: bytes) -> None:
        ns = self.reader.read(buf)[0]
        if not self.answers.due(ns):
            return
        k = round(ns * self.rate / 1e9)
        if self._start_pending:
            self._start_pending = False
            self.exc = Excitation(self.cfg, self.specs, self.seed, self.period_s)
            self.k0 = k
        w = self._zero
        if self.exc is not None:
            row = self.exc.at(k - self.k0)[self.stage - 1]
            w = row if np.isfinite(row).all() else self._zero
        self.answers.reply(ns, self.writer.encode(ns, w))
        self.samples += 1

    def _stop(self) -> None:
        self.exc = None
        self._start_pending = False

    def _on_enable(self, request: SetBool.Request,
                   response: SetBool.Response) -> SetBool.Response:
        if request.data and self.tripped:
            response.success = False
            response.message = ("tripped: the excitation stays off until "
                                f"{self.names.reset_trip}")
        elif request.data:
            if not self.active:
                self._start_pending = True  # from the next sample on
            response.success, response.message = True, "excitation started"
        else:
            self._stop()
            response.success, response.message = True, "excitation stopped"
        self.get_logger().info(response.message)
        self._report()
        return response

    def _on_state(self, msg: String) -> None:
        tripped = msg.data.split(" ", 1)[0] in TRIPPED_STATES
        if tripped and not self.tripped and self.active:
            self.get_logger().warning(f"instability trip: excitation stopped ({msg.data})")
        if tripped:
            self._stop()
        self.tripped = tripped

    def _report(self) -> None:
        level = DiagnosticStatus.WARN if self.tripped else DiagnosticStatus.OK
        self.reports.publish(self.answers.last_ns, [Status(level, (
            "tripped: off" if self.tripped else "active" if self.active else "inactive"), {
            "active": self.active, "spec": " ".join(s.text for s in self.specs),
            "started_at_sample": self.k0 if self.exc is not None else -1,
            "samples": self.samples, "repeats": self.answers.repeats,
            "out_of_order": self.answers.out_of_order, "tripped": self.tripped})])

    def final_reports(self) -> list[SamplePublisher]:
        """Publish the final counters; returns the publishers whose readers should
        acknowledge before the node goes (a clean exit loses nothing)."""
        self._report()
        return [self.pub, self.reports.pub]


main = main_for(ExcitationNode, attach=recorder_part.attach)

if __name__ == "__main__":
    main()
