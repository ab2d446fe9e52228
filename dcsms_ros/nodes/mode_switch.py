"""Mode-switch node: atomic mode changes, the instability trip and the configuration topic.

Services (all ``std_srvs/Trigger``): ``/dcsms/set_mode/<passive|fbc|ffc|fbc_ffc|dfbc|dfbc_ffc>``
and ``/dcsms/reset_trip``. A switch calls ``/dcsms/<controller>/enable`` (``std_srvs/SetBool``)
on every controller the old or the new mode enables; if one does not confirm within
``switch_timeout_s``, every controller that did is set back and the response names the one that
failed. The current mode label (``DFBC+FFC``) is on ``/dcsms/mode`` (transient local, depth 1).

Trip: the band-limited RMS of each stage velocity (:class:`~.trip.TripMonitor`) above
``control.trip_rms_mps`` disables every controller, latches Passive, logs why and reports it on
``/dcsms/diagnostics``; only ``/dcsms/reset_trip`` clears the latch (the mode stays Passive).

A controller whose enable service appears (start-up), or whose ``boot_ns`` in
``/dcsms/diagnostics`` changes (a killed process restarted before its old service expired), is
told the current mode's state, so it comes back in the current mode, fading in. ``/dcsms/config``
(std_msgs/String, transient local) carries the validated flat parameters as a ROS 2 params
YAML file, so a bag records the configuration it was made with.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TwistStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig, params_text
from dcsms_ros.core.modes import ALL_MODES, Mode, controller_ids, enabled_controllers, parse_mode
from dcsms_ros.core.trip import TripMonitor
from dcsms_ros.errors import ConfigError, ModeError
from dcsms_ros.nodes import qos
from dcsms_ros.nodes.hotpath import HotPath
from dcsms_ros.nodes.msgs import status, to_stamp
from dcsms_ros.nodes.params import SELECTORS, NodeConfig, declare_local, declare_schedule
from dcsms_ros.nodes.runtime import main_for
from dcsms_ros.nodes.wire import read_stamped

#: Reader depth of the trip monitor's velocity streams, drained every 50 ms (samples).
TRIP_DEPTH = 4000
#: std_msgs/String, transient local: the flat parameters as params-file YAML.
CONFIG_TOPIC = topics.CONFIG


class ModeSwitchNode(Node):
    """Supervisor: mode services, trip monitor, controller reconciliation."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__("mode_switch", **kwargs)
        self.params = NodeConfig(self, SELECTORS["mode_switch"], self._on_change)
        cfg = self.params.cfg
        n = cfg.plant.num_stages
        lockstep = declare_schedule(self) == "lockstep"
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
        self.num_stages = n
        self.tripped = False
        self.trip_reason = ""
        self.trip_at = (0, 0)
        self._newest_ns = 0
        self.last_result = "start"
        self._switch_lock = threading.Lock()
        self._buf_lock = threading.Lock()
        services = ReentrantCallbackGroup()
        stream = MutuallyExclusiveCallbackGroup()
        self.pub_mode = self.create_publisher(String, topics.MODE, qos.latched())
        self.pub_config = self.create_publisher(String, CONFIG_TOPIC, qos.latched())
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, qos.status())
        self.clients_ = {c: self.create_client(SetBool, topics.enable_service(c),
                                               callback_group=services)
                         for c in self.controllers}
        self._ready = dict.fromkeys(self.controllers, False)
        # a controller killed and restarted keeps its enable service "ready" (DDS liveliness
        # lease): its new boot id in /dcsms/diagnostics is what tells us it came back
        self._boots: dict[str, str] = {}
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics,
                                 qos.status(), callback_group=services)
        for m in ALL_MODES:
            self.create_service(Trigger, topics.set_mode_service(m.value),
                                lambda req, resp, m=m: self._on_set_mode(m, resp),
                                callback_group=services)
        self.create_service(Trigger, topics.RESET_TRIP, self._on_reset_trip,
                            callback_group=services)
        self._monitors = self._make_monitors(cfg)
        self._buffers: list[list[np.ndarray]] = [[] for _ in range(n)]
        self._hot = HotPath(self, self._buf_lock)
        self._trip_subs: list = []
        if self.trip_enabled and self._hot.on:
            # an observer, not on the control path: reliable so the band-pass sees every
            # sample; no executor wakes per sample, _check_trip drains the queues in blocks
            trip_qos = qos.stream_pub(lockstep)
            trip_qos.depth = TRIP_DEPTH
            self._trip_subs = [self._hot.detached(TwistStamped, topics.velocity_topic(
                f"stage{i + 1}"), trip_qos, raw=True) for i in range(n)]
        elif self.trip_enabled:  # DCSMS_HOT_PATH=0: one executor callback per sample
            for i in range(n):
                self.create_subscription(TwistStamped, topics.velocity_topic(f"stage{i + 1}"),
                                         lambda m, i=i: self._on_velocity(i, m),
                                         qos.stream_pub(lockstep), callback_group=stream,
                                         raw=True)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.05, self._check_trip, callback_group=stream, clock=steady)
        self.create_timer(0.5, self._reconcile, callback_group=services, clock=steady)
        self.create_timer(1.0, self._report, clock=steady)
        self._publish_mode()
        self.pub_config.publish(String(data=params_text(self.params.flat)))
        self.get_logger().info(f"mode {self.mode.label}; controllers {self.controllers}")

    def _make_monitors(self, cfg: SystemConfig) -> list[TripMonitor]:
        return [TripMonitor(cfg.control, cfg.plant.rate_hz, cfg.plant.dof)
                for _ in range(cfg.plant.num_stages)]

    def _on_change(self, cfg: SystemConfig, changed: set[str]) -> None:
        if any(n.startswith("control.trip_") for n in changed):
            with self._buf_lock:
                self._monitors = self._make_monitors(cfg)
        self.pub_config.publish(String(data=params_text(self.params.flat)))

    # -- switching ---------------------------------------------------------------------------
    def _call_all(self, states: dict[str, bool], timeout_s: float,
                  wait_for_service: bool = True) -> dict[str, tuple[bool, str]]:
        """Call ``enable(state)`` on each controller in parallel; (ok, message) per controller.

        A controller whose service is not there is only waited for if ``wait_for_service``
        (a trip does not wait); its message starts with ``not available``.
        """
        deadline = time.monotonic() + timeout_s
        out: dict[str, tuple[bool, str]] = {}
        futures = {}
        pending = list(states)
        # every ready controller gets its request at once; the others are waited for in turn
        while pending:
            for c in [c for c in pending if self.clients_[c].service_is_ready()]:
                futures[c] = self.clients_[c].call_async(SetBool.Request(data=states[c]))
                pending.remove(c)
            if not pending:
                break
            if not wait_for_service or time.monotonic() >= deadline:
                for c in pending:
                    out[c] = (False, f"not available (no service {topics.enable_service(c)})")
                break
            time.sleep(0.01)
        # a controller that was ready gets a fair chance to answer even after a long wait
        deadline = max(deadline, time.monotonic() + 0.25)
        for c, fut in futures.items():
            while not fut.done() and time.monotonic() < deadline:
                time.sleep(0.002)
            if not fut.done():
                fut.cancel()
                out[c] = (False, f"no reply within {timeout_s:g} s")
            elif fut.result() is None or not fut.result().success:
                out[c] = (False, fut.result().message if fut.result() else "call failed")
            else:
                out[c] = (True, fut.result().message)
        return out

    def switch(self, target: Mode) -> tuple[bool, str]:
        """Switch every controller to ``target`` atomically; returns (success, message)."""
        if not self._switch_lock.acquire(blocking=False):
            return False, "another mode switch is in progress"
        try:
            if self.tripped and target is not Mode.PASSIVE:
                return False, (f"tripped ({self.trip_reason}); call {topics.RESET_TRIP} before "
                               f"leaving Passive")
            lacking = sorted(enabled_controllers(target, self.num_stages) - set(self.controllers))
            if lacking:
                return False, f"{target.label} needs {', '.join(lacking)}, not in this graph"
            old = self.mode
            want = enabled_controllers(target, self.num_stages)
            had = enabled_controllers(old, self.num_stages)
            involved = [c for c in self.controllers if c in want or c in had]
            res = self._call_all({c: c in want for c in involved}, self.switch_timeout_s)
            failed = [c for c in involved if not res[c][0]]
            if failed:
                # everyone who may have applied the request goes back (repeating a state is
                # harmless); only a controller that never got it is left alone
                back = self._call_all({c: c in had for c in involved
                                       if not res[c][1].startswith("not available")},
                                      self.switch_timeout_s)
                stuck = [c for c, r in back.items() if not r[0]]
                msg = (f"switch to {target.label} failed: "
                       + "; ".join(f"{c}: {res[c][1]}" for c in failed)
                       + f"; rolled back to {old.label}"
                       + (f" (rollback failed for {', '.join(stuck)})" if stuck else ""))
                self.get_logger().error(msg)
                return False, msg
            self.mode = target
            self._publish_mode()
            msg = f"mode {target.label}" + (": " + ", ".join(
                f"{c} {'on' if c in want else 'off'}" for c in involved) if involved else "")
            self.get_logger().info(msg)
            return True, msg
        finally:
            self._switch_lock.release()

    def _on_set_mode(self, mode: Mode, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self.switch(mode)
        self.last_result = response.message
        return response

    def _publish_mode(self) -> None:
        self.pub_mode.publish(String(data=self.mode.label))

    def _reconcile(self) -> None:
        """Tell a controller whose service (re)appeared the state the current mode wants."""
        if self._switch_lock.locked():
            return
        want = enabled_controllers(self.mode, self.num_stages)
        for c, client in self.clients_.items():
            ready = client.service_is_ready()
            if ready and not self._ready[c]:
                self._tell(c, c in want, "joined")
            elif not ready and self._ready[c]:
                self.get_logger().warning(f"{c} left the graph (enable service gone)")
            self._ready[c] = ready

    def _tell(self, c: str, state: bool, why: str) -> None:
        fut = self.clients_[c].call_async(SetBool.Request(data=state))
        fut.add_done_callback(lambda f: self.get_logger().info(
            f"{c} {why}: {f.result().message if f.result() else 'no reply'}"))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name not in self.clients_:
                continue
            boot = next((kv.value for kv in st.values if kv.key == "boot_ns"), None)
            if boot is None or self._boots.get(st.name) == boot:
                continue
            if self._switch_lock.locked():
                return  # a switch tells everyone anyway; the next report is judged again
            known = st.name in self._boots
            self._boots[st.name] = boot
            if known:  # a new process under the same name: give it the current mode's state
                self._tell(st.name, st.name in enabled_controllers(self.mode, self.num_stages),
                           "restarted")

    # -- trip --------------------------------------------------------------------------------
    def _on_velocity(self, i: int, buf: bytes) -> None:
        self._newest_ns, v = read_stamped(buf, TwistStamped, self._monitors[i].channels)
        self._buffers[i].append(v)

    def _check_trip(self) -> None:
        for i, sub in enumerate(self._trip_subs):
            HotPath.drain(sub, lambda m, i=i: self._on_velocity(i, m))
        with self._buf_lock:
            worst = None
            for i, (mon, buf) in enumerate(zip(self._monitors, self._buffers, strict=True)):
                if not buf:
                    continue
                block, self._buffers[i] = np.array(buf), []
                rms = mon.update(block)
                if mon.tripped() and worst is None:
                    j = int(np.argmax(rms / mon.threshold))
                    band = self.params.cfg.control.trip_band_hz
                    worst = (f"stage{i + 1} velocity RMS {rms[j]:.3g} m/s (axis {j}) above "
                             f"{mon.threshold:g} m/s in {band[0]:g}-{band[1]:g} Hz")
        if worst is not None and not self.tripped:
            self._trip(worst)

    def _trip(self, reason: str) -> None:
        self.tripped = True
        self.trip_reason = reason
        # when: wall (CLOCK_MONOTONIC) and the stamp of the newest velocity sample judged
        self.trip_at = (time.monotonic_ns(), self._newest_ns)
        self.get_logger().error(f"instability trip: {reason}; latching Passive until "
                                f"{topics.RESET_TRIP}")
        with self._switch_lock:
            res = self._call_all(dict.fromkeys(self.controllers, False), self.switch_timeout_s,
                                 wait_for_service=False)
            self.mode = Mode.PASSIVE
            self._publish_mode()
        bad = [c for c, r in res.items() if not r[0]]
        if bad:
            self.get_logger().error(f"trip: could not disable {', '.join(bad)}")
        self._report()

    def _on_reset_trip(self, request: Trigger.Request,
                       response: Trigger.Response) -> Trigger.Response:
        if not self.tripped:
            response.success, response.message = True, "no trip latched"
            return response
        with self._buf_lock:
            for mon in self._monitors:
                mon.reset()
            self._buffers = [[] for _ in self._buffers]
        old = self.trip_reason
        self.tripped, self.trip_reason = False, ""
        response.success = True
        response.message = f"trip cleared (was: {old}); mode stays {self.mode.label}"
        self.get_logger().info(response.message)
        return response

    def _report(self) -> None:
        want = enabled_controllers(self.mode, self.num_stages)
        missing = [c for c in want if c in self._ready and not self._ready[c]]
        level = (DiagnosticStatus.ERROR if self.tripped else
                 DiagnosticStatus.WARN if missing else DiagnosticStatus.OK)
        msg = (f"TRIPPED: {self.trip_reason}" if self.tripped else
               f"degraded: {', '.join(missing)} absent" if missing else self.mode.label)
        values = {"mode": self.mode.label, "tripped": self.tripped,
                  "trip_reason": self.trip_reason, "last_switch": self.last_result,
                  "trip_mono_ns": self.trip_at[0], "trip_sample_ns": self.trip_at[1]}
        values.update({f"rms_stage{i + 1}_mps": " ".join(f"{x:.3g}" for x in m.rms)
                       for i, m in enumerate(self._monitors)})
        values.update({c: "present" if r else "absent" for c, r in self._ready.items()})
        arr = DiagnosticArray()
        # sample time like the other nodes' reports (the node itself runs on the wall clock)
        arr.header.stamp = (to_stamp(self._newest_ns) if self._newest_ns
                            else self.get_clock().now().to_msg())
        arr.status = [status("mode_switch", level, msg, values)]
        self.pub_diag.publish(arr)


main = main_for(ModeSwitchNode, multithreaded=True)

if __name__ == "__main__":
    main()
