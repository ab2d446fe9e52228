"""Mode-switch node: atomic mode changes, the instability trip, the stability guard and the
configuration topic (names relative to the graph's namespace).

Services (all ``std_srvs/Trigger``): ``set_mode/<passive|fbc|ffc|fbc_ffc|dfbc|dfbc_ffc>`` and
``reset_trip``. A switch calls ``<controller>/enable`` (``std_srvs/SetBool``) on every controller
the old or the new mode enables; if one does not confirm within ``switch_timeout_s``, every
controller that did is set back and the response names the one that failed. A switch into a
mode the model of the running configuration calls unstable is refused with the pole
(:mod:`dcsms_ros.ros.stability`; ``allow_unstable`` lets it through). The mode label is on ``mode``
(transient local, depth 1).

Supervisor and trip (what is judged: :mod:`.mode_switch_supervisor`): at every checkpoint the
supervisor may ride through in a calmer mode, re-engage the user's mode, trip to Passive or
latch; each transition switches the controllers, is logged and published on
``supervisor/state`` (transient local); a user's switch it refuses is refused with its reason.
Without it a trip disables every controller, latches Passive, logs why and reports it on
``/diagnostics``; only ``reset_trip`` clears the latch (the mode stays Passive). Lockstep: the
plant asks about each checkpoint (``trip/check``) once every controller answered its last
sample, and waits for the verdict (``trip/checked``, sent after the controllers confirmed a
trip's disable), so the trip lands on the batch engine's sample. Real time: the velocities
are judged every 50 ms of wall time.

``config`` (std_msgs/String, transient local) carries the whole configuration as a ROS 2
params file, including tuning changed on the controller nodes (learnt from
``/parameter_events``), so a bag records the configuration it was made with.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import ParameterEvent
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import qos_profile_parameter_events
from std_msgs.msg import Int64, String
from std_srvs.srv import Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.config import params_text
from dcsms_ros.core.modes import ALL_MODES, Mode, controller_ids, enabled_controllers, parse_mode
from dcsms_ros.core.supervisor import State, Transition
from dcsms_ros.errors import ConfigError, ModeError
from dcsms_ros.nodes.mode_switch_checkpoints import CheckpointAnswers
from dcsms_ros.nodes.mode_switch_clients import ControllerClients
from dcsms_ros.nodes.mode_switch_supervisor import TableWatch
from dcsms_ros.ros import qos
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.msgs import sample_ns
from dcsms_ros.ros.params import (
    MUTABLE_PREFIXES,
    SELECTORS,
    NodeConfig,
    declare_local,
    declare_schedule,
)
from dcsms_ros.ros.reports import Reports, Status
from dcsms_ros.ros.runtime import main_for
from dcsms_ros.ros.stability import StabilityGuard


class ModeSwitchNode(GraphNode, Hosted):
    """Supervisor: mode services, trip, stability guard, controller reconciliation."""

    hot: HotPath  # every instance has one (Hosted declares it optional)

    def __init__(self, node_name: str = "mode_switch", **kwargs: Any) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.params = NodeConfig(self, SELECTORS["mode_switch"], self._on_change)
        cfg = self.params.cfg
        n = cfg.plant.num_stages
        self.lockstep = declare_schedule(self) == "lockstep"
        try:
            self.mode = parse_mode(declare_local(self, "initial_mode", "passive",
                                                 "Mode at start (its controllers must be "
                                                 "started with enabled:=true)"))
        except ModeError as exc:
            raise ConfigError(f"node mode_switch: initial_mode: {exc}") from None
        wanted = declare_local(self, "controllers", list(controller_ids(n)),
                               "Controller ids this graph runs")
        self.controllers = [c for c in controller_ids(n) if c in wanted]
        self.switch_timeout_s = declare_local(self, "switch_timeout_s", 2.0, "Longest wait "
                                              "for the controllers to confirm a switch [s]",
                                              read_only=False, lo=0.01, hi=60.0)
        self.trip_enabled = declare_local(self, "trip_enabled", True, "Watch the stage "
                                          "velocities and latch Passive on instability")
        self.guard = StabilityGuard(self, listen=False, late=not self.lockstep)
        self.guard.flat, self.guard.mode = dict(self.params.flat), self.mode
        # the initial mode passes the guard a switch passes: nothing unstable runs at start
        refused = self.guard.refuse_mode(self.mode, cfg)
        if refused is not None:
            raise ConfigError(f"node mode_switch: initial_mode: {refused}")
        self.params.vet = self.guard.vet
        self.num_stages = n
        self.tripped, self.trip_reason = False, ""
        self.trip_at = (0, 0)
        self.last_result = "start"
        #: The mode the controllers must follow after a trip or a supervisor's decision, and
        #: what decided it (None: nothing to follow).
        self._target: tuple[Mode, str] | None = None
        self._following = False
        self.hot = HotPath(self)
        services = ReentrantCallbackGroup()
        self.pub_mode = self.create_publisher(String, topics.LOCAL.mode, qos.events())
        self.pub_config = self.create_publisher(String, topics.LOCAL.config, qos.latched())
        self.reports = Reports(self, self.hot)
        self.ctl = ControllerClients(self, self.controllers, services)
        for c in self.controllers:
            self.create_subscription(Int64, topics.LOCAL.boot(c), partial(self._on_boot, c),
                                     qos.latched(), callback_group=services)
        self.create_subscription(ParameterEvent, topics.PARAMETER_EVENTS, self._on_param_event,
                                 qos_profile_parameter_events, callback_group=services)
        for m in ALL_MODES:
            self.create_service(Trigger, topics.LOCAL.set_mode(m.value),
                                partial(self._on_set_mode_request, m),
                                callback_group=services)
        self.create_service(Trigger, topics.LOCAL.reset_trip, self._on_reset_trip,
                            callback_group=services)
        self.pub_state = self.create_publisher(String, topics.LOCAL.supervisor_state,
                                               qos.events())
        self.watch = TableWatch(self.hot, cfg, self.mode, self.guard, self.lockstep,
                                self.trip_enabled)
        # lockstep: the hot loop hands a switch of the controllers to the executor (it waits
        # for their replies there) and answers the plant once they confirmed
        self._follow_gc = self.create_guard_condition(self._follow, services)
        self.checks = (CheckpointAnswers(
            self, self.hot, self.watch, self._judge_checkpoint, lambda: self._target is not None,
            lambda: "tripped" if self.tripped else "ok",
            lambda: self.params.cfg.control.lockstep_timeout_s)
            if self.trip_enabled and self.lockstep else None)
        if self.trip_enabled and self.checks is None:
            self.housekeeping(0.05, self._judge_timer, MutuallyExclusiveCallbackGroup())
        self.housekeeping(0.5, self._reconcile, services)
        self.housekeeping(1.0, self._report)
        self._publish_mode()
        self._publish_config()
        self.get_logger().info(f"mode {self.mode.label}; controllers {self.controllers}"
                               f"{'; trip checkpoints' if self.checks else ''}"
                               f"{'; supervisor on' if self.watch.sfeed else ''}")
        self._publish_state(None)
        self.hot.start()

    # -- configuration -----------------------------------------------------------------------
    def _publish_config(self) -> None:
        self.pub_config.publish(String(data=params_text(self.guard.flat)))

    def _on_change(self, cfg: Any, changed: set[str]) -> None:
        self.guard.flat.update({k: self.params.flat[k] for k in changed})
        self.watch.retune(cfg, changed)
        self._publish_config()

    def _on_param_event(self, msg: ParameterEvent) -> None:
        """Tuning changed on a controller of this graph: merge it, republish the config."""
        ns, _, node = msg.node.rpartition("/")
        if node not in self.controllers or (ns or "/") != self.get_namespace():
            return
        got = {p.name: parameter_value_to_python(p.value) for p in msg.changed_parameters
               if p.name.startswith(MUTABLE_PREFIXES) and p.name in self.params.names}
        got = {k: (list(v) if isinstance(v, (list, tuple)) else v)
               for k, v in got.items()}
        if got and any(self.guard.flat.get(k) != v for k, v in got.items()):
            self.guard.flat.update(got)
            cfg = self.guard.config()
            if cfg is not None:
                self.watch.floor_retuned(cfg)
            self._publish_config()

    # -- switching ---------------------------------------------------------------------------
    async def switch(self, target: Mode) -> tuple[bool, str]:
        """Switch every controller to ``target`` atomically; returns (success, message).

        A coroutine: it waits for the controllers' replies suspended, so the node's other
        callbacks (the trip, reports) go on meanwhile; no other switch starts before it ends.
        """
        if self.ctl.busy:
            return False, "another mode switch is in progress"
        if self.watch.sfeed is not None:
            refused = self.watch.sfeed.sup.refusal(target)
            if refused:
                return False, refused
        elif self.tripped and target is not Mode.PASSIVE:
            return False, (f"tripped ({self.trip_reason}); call {topics.LOCAL.reset_trip} "
                           f"before leaving Passive")
        lacking = sorted(enabled_controllers(target, self.num_stages) - set(self.controllers))
        if lacking:
            return False, f"{target.label} needs {', '.join(lacking)}, not in this graph"
        refused = self.guard.refuse_mode(target)
        if refused:
            return False, refused
        old = self.mode
        want = enabled_controllers(target, self.num_stages)
        had = enabled_controllers(old, self.num_stages)
        involved = [c for c in self.controllers if c in want or c in had]
        res = await self.ctl.call_all({c: c in want for c in involved},
                                      self.switch_timeout_s)
        failed = [c for c in involved if not res[c][0]]
        if failed:
            # everyone who may have applied the request goes back (repeating a state is
            # harmless); only a controller that never got it is left alone
            back = await self.ctl.call_all({c: c in had for c in involved
                                            if not res[c][1].startswith("not available")},
                                           self.switch_timeout_s)
            stuck = [c for c, r in back.items() if not r[0]]
            msg = (f"switch to {target.label} failed: "
                   + "; ".join(f"{c}: {res[c][1]}" for c in failed)
                   + f"; rolled back to {old.label}"
                   + (f" (rollback failed for {', '.join(stuck)})" if stuck else ""))
            self.get_logger().error(msg)
            return False, msg
        self._set_mode(target)
        if self.watch.sfeed is not None:
            self._publish_state(self.watch.requested(target))
            self.tripped = False
        msg = f"mode {target.label}" + (": " + ", ".join(
            f"{c} {'on' if c in want else 'off'}" for c in involved) if involved else "")
        self.get_logger().info(msg)
        return True, msg

    async def _on_set_mode_request(self, mode: Mode, request: Trigger.Request,
                                   response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = await self.switch(mode)
        self.last_result = response.message
        return response

    def _set_mode(self, mode: Mode) -> None:
        self.mode = self.guard.mode = mode
        self._publish_mode()

    def _publish_mode(self) -> None:
        self.pub_mode.publish(String(data=self.mode.label))

    def _want(self, c: str) -> bool:
        return c in enabled_controllers(self.mode, self.num_stages)

    def _reconcile(self) -> None:
        if not self.ctl.busy:
            self.ctl.reconcile(self._want)

    def _on_boot(self, c: str, msg: Int64) -> None:
        # a switch in progress tells everyone anyway
        self.ctl.on_boot(c, msg.data, self._want, quiet=self.ctl.busy)

    # -- trip --------------------------------------------------------------------------------
    async def _judge_timer(self) -> None:
        """Real time: judge what arrived; the controllers follow a decision before the next
        judgement (this timer waits for them)."""
        self._judge()
        await self._follow()

    def _judge(self, through_ns: int | None = None, drain: bool = True) -> None:
        """Judge the streams through ``through_ns`` (None: what arrived); a trip or the
        supervisor's decision sets the mode the controllers must follow (:meth:`_follow`).
        ``drain=False``: the queues were just drained (a checkpoint's samples are in)."""
        if drain:
            self.watch.drain()
        if self.watch.sfeed is not None:
            transitions = self.watch.sfeed.step(through_ns)
            if transitions:
                self._supervise(transitions)
            return
        # judged on after a trip too: the reported RMS shows when the table has settled
        trip = self.watch.feed.judge(through_ns)
        if trip is not None and not self.tripped:
            self._trip(trip.reason, self.watch.feed.trip_ns)

    def _supervise(self, transitions: list[Transition]) -> None:
        """Carry out the supervisor's decisions: every transition is published and logged;
        the controllers follow the last one's mode (lockstep: before the plant hears the
        verdict, so the new mode runs from the next sample, as in the batch engine)."""
        assert self.watch.sfeed is not None
        for tr in transitions:
            # rclpy: one call site, one severity (it raises otherwise)
            if tr.state in (State.TRIPPED, State.LATCHED):
                self.get_logger().error(f"supervisor: {tr.label}")
            else:
                self.get_logger().warning(f"supervisor: {tr.label}")
            self._publish_state(tr)
        last = transitions[-1]
        self.tripped = last.state in (State.TRIPPED, State.LATCHED)
        self.trip_reason = last.reason if self.tripped else ""
        if self.tripped:
            self.trip_at = (time.monotonic_ns(), sample_ns(last.sample, self.watch.feed.rate))
        if last.mode is not self.mode:
            self._target = (last.mode, f"supervisor: {last.mode.label}: could not switch")
        else:
            self._report()

    def _judge_checkpoint(self, stamp_ns: int) -> None:
        """Lockstep: judge the asked checkpoint; a switch it decides is handed to the
        executor (:meth:`_follow` waits there for the controllers' replies)."""
        # CheckpointAnswers drained the queues to see that the samples are in: a second
        # drain would read four empty queues
        self._judge(stamp_ns, drain=False)
        if self._target is not None:
            self._follow_gc.trigger()

    async def _follow(self) -> None:
        """Switch the controllers to the mode a trip or the supervisor decided (after a
        switch in progress); then report and, in lockstep, answer the plant."""
        # the executor runs other callbacks while this one awaits the replies: a second
        # trigger of the guard condition (lockstep) or the judge timer meanwhile has nothing to do
        if self._target is None or self._following:
            return
        self._following = True
        mode, why = self._target
        want = enabled_controllers(mode, self.num_stages)
        try:
            res = await self.ctl.call_all({c: c in want for c in self.controllers},
                                          self.switch_timeout_s, wait_for_service=False)
        finally:
            self._following = False
        self._set_mode(mode)
        self._target = None
        bad = [c for c, r in res.items() if not r[0]]
        if bad:
            self.get_logger().error(f"{why} {', '.join(bad)}")
        self._report()
        if self.checks is not None:  # lockstep: the verdict waited for the controllers
            self.checks.followed()

    def _publish_state(self, tr: Transition | None) -> None:
        """``supervisor/state``: the transition's label; at start ``ENGAGED`` (or ``OFF``
        without a supervisor)."""
        if tr is not None:
            text = tr.label
        elif self.watch.sfeed is None:
            text = f"OFF {self.mode.label} at 0.0000 s: supervisor disabled"
        else:
            text = f"ENGAGED {self.mode.label} at 0.0000 s: start"
        self.pub_state.publish(String(data=text))

    def _trip(self, reason: str, stamp_ns: int) -> None:
        self.tripped, self.trip_reason = True, reason
        # when: wall (CLOCK_MONOTONIC) and the stamp of the sample whose checkpoint tripped
        self.trip_at = (time.monotonic_ns(), stamp_ns)
        self.get_logger().error(f"instability trip: {reason}; latching Passive until "
                                f"{topics.LOCAL.reset_trip}")
        self.pub_state.publish(String(data=self.watch.latched(reason, stamp_ns)))
        self._target = (Mode.PASSIVE, "trip: could not disable")

    def _on_reset_trip(self, request: Trigger.Request,
                       response: Trigger.Response) -> Trigger.Response:
        if not self.tripped:
            response.success, response.message = True, "no trip latched"
            return response
        self.pub_state.publish(String(data=self.watch.reset()))
        old, self.tripped, self.trip_reason = self.trip_reason, False, ""
        response.success = True
        response.message = f"trip cleared (was: {old}); mode stays {self.mode.label}"
        self.get_logger().info(response.message)
        return response

    def _report(self) -> None:
        missing = [c for c in self.controllers if self._want(c) and not self.ctl.ready[c]]
        sup = self.watch.sfeed.sup if self.watch.sfeed is not None else None
        riding = sup is not None and sup.state in (State.RIDE_THROUGH, State.RECOVERING)
        level = (DiagnosticStatus.ERROR if self.tripped else
                 DiagnosticStatus.WARN if missing or riding else DiagnosticStatus.OK)
        msg = (f"TRIPPED: {self.trip_reason}" if self.tripped else
               f"degraded: {', '.join(missing)} absent" if missing else
               f"{sup.state.value} {self.mode.label}: {sup.reason}" if riding and sup else
               self.mode.label)
        values: dict[str, object] = {
            "mode": self.mode.label, "tripped": self.tripped, "trip_reason": self.trip_reason,
            "last_switch": self.last_result, "trip_mono_ns": self.trip_at[0],
            "trip_sample_ns": self.trip_at[1], "allow_unstable": self.guard.allow,
            **self.watch.status()}
        values.update({c: "present" if r else "absent" for c, r in self.ctl.ready.items()})
        # sample time like the other nodes' reports (the node itself runs on the wall clock)
        judged = max(self.watch.feed.judged_ns, 0)
        self.reports.publish(judged or self.get_clock().now().nanoseconds,
                             [Status(level, msg, values)])


main = main_for(ModeSwitchNode)

if __name__ == "__main__":
    main()
