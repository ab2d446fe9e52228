"""Topic and service names of the graph (pure constants, shared by nodes, CLI and analysis).

Every stream carries SI units (REP-103); ``header.stamp`` is the sample time. The graph's
names are relative to its namespace (default :data:`NAMESPACE`; ``dcsms up --namespace``, the
launch argument ``namespace``), so two isolation tables run side by side on one ROS network:
the nodes use :data:`LOCAL` (relative names, resolved by ROS in the node's namespace), tools
outside the graph use ``Names(namespace)``. ``/clock`` and ``/diagnostics`` are global, as ROS
tools expect them (status names carry the namespace, :func:`status_name`).

The module-level constants and functions give the names in the default namespace (bags, the
analysis and the tests use them).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from dcsms_ros.errors import ConfigError

NAMESPACE = "/dcsms"

#: rosgraph_msgs/Clock, published by the plant simulator.
CLOCK = "/clock"
#: diagnostic_msgs/DiagnosticArray: faults, trips, counters of every node (status names carry
#: the graph's namespace); the ROS standard topic (diagnostic_aggregator, rqt_robot_monitor).
DIAGNOSTICS = "/diagnostics"
#: rcl_interfaces/ParameterEvent: every node's parameter changes (ROS standard).
PARAMETER_EVENTS = "/parameter_events"

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def check_namespace(ns: str) -> str:
    """``ns`` as an absolute ROS namespace without a trailing slash (``dcsms`` -> ``/dcsms``).

    Raises
    ------
    ConfigError
        If a token is empty or not ``[A-Za-z_][A-Za-z0-9_]*``.
    """
    text = ns.strip()
    parts = list(text.strip("/").split("/")) if text.strip("/") else []
    bad = [p for p in parts if not _TOKEN.match(p)]
    if bad or "//" in text:
        raise ConfigError(f"namespace {ns!r}: each part must match [A-Za-z_][A-Za-z0-9_]* "
                          f"(e.g. /dcsms or /lab/table2)")
    return "/" + "/".join(parts)


@dataclass(frozen=True)
class Names:
    """The graph's names in namespace ``ns``; ``ns=None``: relative (inside the graph)."""

    ns: str | None = NAMESPACE

    def _join(self, rel: str) -> str:
        if self.ns is None:
            return rel
        return f"{self.ns.rstrip('/')}/{rel}"

    @property
    def sensors_raw(self) -> str:
        """sensor_msgs/JointState: one entry per geophone channel, ``velocity`` in m/s as the
        sensor reports it (output voltage / nominal sensitivity, with the geophone roll-off)."""
        return self._join("sensors/raw")

    @property
    def actuators_applied(self) -> str:
        """sensor_msgs/JointState: force actually applied by each actuator, ``effort`` in N."""
        return self._join("actuators/applied")

    @property
    def mode(self) -> str:
        """std_msgs/String, transient local depth 1: the current mode label (``DFBC+FFC``)."""
        return self._join("mode")

    @property
    def config(self) -> str:
        """std_msgs/String, transient local depth 1: the configuration as a params file."""
        return self._join("config")

    @property
    def reset_trip(self) -> str:
        """std_srvs/Trigger: clear a latched instability trip."""
        return self._join("reset_trip")

    @property
    def supervisor_state(self) -> str:
        """std_msgs/String, transient local depth 1, published by mode_switch at every
        supervisor transition: ``STATE MODE at T s: reason`` (T: plant time of the sample it
        took effect after; :attr:`dcsms_ros.core.supervisor.Transition.label`)."""
        return self._join("supervisor/state")

    @property
    def plant_held(self) -> str:
        """std_msgs/Int64, transient local depth 1, plant -> ``dcsms up`` (lockstep): the plant
        holds before sample ``data`` (its ``hold_at_s``) until the scheduled switch is made."""
        return self._join("plant/held")

    @property
    def plant_finished(self) -> str:
        """std_msgs/Bool, transient local depth 1: True once the plant stepped its last sample
        (``duration_s``), so a supervisor tells a finished run from a crash."""
        return self._join("plant/finished")

    @property
    def trip_check(self) -> str:
        """std_msgs/Header, plant -> mode_switch (lockstep): judge the trip checkpoint that
        ends with the sample stamped ``stamp``."""
        return self._join("trip/check")

    @property
    def trip_checked(self) -> str:
        """std_msgs/Header, mode_switch -> plant (lockstep): checkpoint ``stamp`` judged (and
        on a trip every controller disabled); ``frame_id`` ``ok`` or ``tripped``."""
        return self._join("trip/checked")

    def ready(self, role: str) -> str:
        """std_msgs/Bool, transient local depth 1 (real time): True once DDS matched the
        per-sample readers and writers of control-path node ``role`` (``sensor_decoupling``, a
        controller id, ``excitation``); the plant starts after hearing each
        (:mod:`dcsms_ros.ros.readiness`)."""
        return self._join(f"{role}/ready")

    def velocity(self, body: str) -> str:
        """geometry_msgs/TwistStamped: decoupled velocity of ``body`` at its reference point
        (m/s, rad/s), published by the sensor-decoupling node."""
        return self._join(f"velocity/{body}")

    def truth(self, body: str) -> str:
        """geometry_msgs/TwistStamped: the simulator's true velocity of ``body``."""
        return self._join(f"truth/{body}")

    def force(self, controller: str) -> str:
        """geometry_msgs/WrenchStamped: the force command of one controller (N, N*m) at the
        reference point of the stage its actuators push (frame_id = that stage)."""
        return self._join(f"force/{controller}")

    def set_mode(self, mode_value: str) -> str:
        """std_srvs/Trigger: switch the whole graph to one mode atomically."""
        return self._join(f"set_mode/{mode_value}")

    def enable(self, controller: str) -> str:
        """std_srvs/SetBool: enable or disable one controller (gains fade in and out)."""
        return self._join(f"{controller}/enable")

    def boot(self, controller: str) -> str:
        """std_msgs/Int64, transient local depth 1: when the controller's process started (ns
        since the epoch); a new value under the same name is a restarted process."""
        return self._join(f"{controller}/boot")

    def heard(self, controller: str) -> str:
        """std_msgs/Int64, transient local depth 1, plant -> controller (real time): the
        ``boot`` of the controller process whose force the plant has taken; a (re)started
        controller fades in once it reads its own (:mod:`dcsms_ros.ros.heard`)."""
        return self._join(f"plant/heard/{controller}")

    def set_parameters(self, node: str) -> str:
        """rcl_interfaces/SetParameters of node ``node`` of the graph."""
        return self._join(f"{node}/set_parameters")

    def status(self, node: str, sub: str = "") -> str:
        """Diagnostic status name of ``node`` (and of one of its parts ``sub``)."""
        return status_name(self._join(node) if self.ns is not None else node, sub)

    def local_status(self, name: str) -> str | None:
        """``name`` of a status on /diagnostics relative to this namespace (``plant_simulator``,
        ``plant_simulator/fb_stage1``), None if it belongs to another graph."""
        prefix = (self.ns or "").strip("/")
        if not prefix:
            return name
        return name[len(prefix) + 1:] if name.startswith(prefix + "/") else None


def status_name(fqn: str, sub: str = "") -> str:
    """Status name of the node with fully qualified name ``fqn`` (``dcsms/plant_simulator``;
    ``dcsms/plant_simulator/fb_stage1`` for a part ``sub``)."""
    base = fqn.strip("/")
    return f"{base}/{sub}" if sub else base


#: Names inside the graph (relative: each node resolves them in its own namespace).
LOCAL = Names(None)
#: Names of the default graph.
DEFAULT = Names(NAMESPACE)

#: Node name of the plant simulator (the actuator node a controller waits for by default).
PLANT_ID = "plant_simulator"

#: Id of the excitation source (``nodes/excitation.py``): it publishes on :meth:`Names.force` of
#: it a wrench (N, N*m) on the stage named by its ``frame_id``, which the plant sums with the
#: controllers' before allocation.
EXCITATION_ID = "excitation"
EXCITATION = DEFAULT.force(EXCITATION_ID)

SENSORS_RAW = DEFAULT.sensors_raw
ACTUATORS_APPLIED = DEFAULT.actuators_applied
MODE = DEFAULT.mode
SUPERVISOR_STATE = DEFAULT.supervisor_state
CONFIG = DEFAULT.config
RESET_TRIP = DEFAULT.reset_trip


def body_names(num_stages: int) -> tuple[str, ...]:
    """Body names in cascade order: ``ground``, ``stage1`` … ``stageN``."""
    return ("ground", *(f"stage{i}" for i in range(1, num_stages + 1)))


def velocity_topic(body: str, ns: str | None = NAMESPACE) -> str:
    """:meth:`Names.velocity` in namespace ``ns`` (None: relative)."""
    return Names(ns).velocity(body)


def truth_topic(body: str, ns: str | None = NAMESPACE) -> str:
    """:meth:`Names.truth` in namespace ``ns`` (None: relative)."""
    return Names(ns).truth(body)


def force_topic(controller: str, ns: str | None = NAMESPACE) -> str:
    """:meth:`Names.force` in namespace ``ns`` (None: relative)."""
    return Names(ns).force(controller)


def set_mode_service(mode_value: str, ns: str | None = NAMESPACE) -> str:
    """:meth:`Names.set_mode` in namespace ``ns`` (None: relative)."""
    return Names(ns).set_mode(mode_value)


def enable_service(controller: str, ns: str | None = NAMESPACE) -> str:
    """:meth:`Names.enable` in namespace ``ns`` (None: relative)."""
    return Names(ns).enable(controller)
