"""Topic and service names of the graph (pure constants, shared by nodes, CLI and analysis).

Every stream carries SI units (REP-103); ``header.stamp`` is the sample time.
"""

from __future__ import annotations

NAMESPACE = "/dcsms"

#: rosgraph_msgs/Clock, published by the plant simulator.
CLOCK = "/clock"
#: sensor_msgs/JointState: one entry per geophone channel, ``velocity`` in m/s as the sensor
#: reports it (output voltage / nominal sensitivity, so it still has the geophone roll-off).
SENSORS_RAW = "/dcsms/sensors/raw"
#: sensor_msgs/JointState: force actually applied by each actuator channel, ``effort`` in N.
ACTUATORS_APPLIED = "/dcsms/actuators/applied"
#: std_msgs/String, transient local depth 1: the current mode label (e.g. ``DFBC+FFC``).
MODE = "/dcsms/mode"
#: std_msgs/String, transient local depth 1: the configuration as a ROS 2 params file.
CONFIG = "/dcsms/config"
#: diagnostic_msgs/DiagnosticArray: faults, trips, counters.
DIAGNOSTICS = "/dcsms/diagnostics"


def body_names(num_stages: int) -> tuple[str, ...]:
    """Body names in cascade order: ``ground``, ``stage1`` … ``stageN``."""
    return ("ground",) + tuple(f"stage{i}" for i in range(1, num_stages + 1))


def velocity_topic(body: str) -> str:
    """geometry_msgs/TwistStamped: decoupled rigid-body velocity of ``body`` at its reference
    point (m/s, rad/s), published by the sensor-decoupling node."""
    return f"{NAMESPACE}/velocity/{body}"


def truth_topic(body: str) -> str:
    """geometry_msgs/TwistStamped: the simulator's true velocity of ``body`` (m/s, rad/s)."""
    return f"{NAMESPACE}/truth/{body}"


def force_topic(controller: str) -> str:
    """geometry_msgs/WrenchStamped: the force command of one controller (N, N*m) at the
    reference point of the stage its actuators push (frame_id = that stage)."""
    return f"{NAMESPACE}/force/{controller}"


#: Id of the excitation source (:mod:`.excitation`): its wrench topic is ``force_topic`` of it.
EXCITATION_ID = "excitation"
#: geometry_msgs/WrenchStamped: the excitation wrench (N, N*m) on the stage named by its
#: ``frame_id``, summed by the plant with the controllers' forces before allocation.
EXCITATION = f"{NAMESPACE}/force/{EXCITATION_ID}"


def set_mode_service(mode_value: str) -> str:
    """std_srvs/Trigger: switch the whole graph to one mode atomically."""
    return f"{NAMESPACE}/set_mode/{mode_value}"


def enable_service(controller: str) -> str:
    """std_srvs/SetBool: enable or disable one controller (gains fade in and out)."""
    return f"{NAMESPACE}/{controller}/enable"


#: std_srvs/Trigger: clear a latched instability trip.
RESET_TRIP = "/dcsms/reset_trip"
