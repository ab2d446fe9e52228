"""The node graph of one isolation table, defined once.

:func:`define_graph` takes a configuration (N stages, 1dof or 6dof) and the run's settings and
lists the nodes: name, executable, parameters, remappings, and whether the node is on the
per-sample control path. Everything that starts a graph uses it: ``launch/dcsms.launch.py``,
``dcsms up`` (one process per node, or ``--composed``), ``dcsms sim --engine graph`` and
``dcsms demo``. Plain Python (no rclpy), so the launch file can import it too.

The parameters of a run are one ROS 2 params file (:meth:`GraphSpec.params_document`): the
validated configuration and the schedule for every node (``/**``), then each node's own
settings under its fully qualified name. All names are relative to the graph's namespace.

Adding a node (e.g. an excitation source) is one :class:`NodeSpec` in :func:`define_graph`
and, for ``--composed``, its class in :data:`NODE_CLASSES`.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import ControllerId, Mode, controller_ids, enabled_controllers

#: Executable (console script, module ``dcsms_ros.nodes.<executable>``) -> node class, for the
#: composed deployment (``module:Class``).
NODE_CLASSES = {
    "plant_simulator": "dcsms_ros.nodes.plant_simulator:PlantSimulatorNode",
    "sensor_decoupling": "dcsms_ros.nodes.sensor_decoupling:SensorDecouplingNode",
    "feedback_controller": "dcsms_ros.nodes.feedback_controller:FeedbackControllerNode",
    "feedforward_controller": "dcsms_ros.nodes.feedforward_controller:FeedforwardControllerNode",
    "mode_switch": "dcsms_ros.nodes.mode_switch:ModeSwitchNode",
    "excitation": "dcsms_ros.nodes.excitation:ExcitationNode",
    "recorder": "dcsms_ros.nodes.recorder:Recorder",
}
SCHEDULES = ("lockstep", "realtime")
#: Environment variable: SCHED_FIFO priority (1-99) of a node process's hot thread (only it:
#: :func:`dcsms_ros.ros.runtime.rt_priority_from_env`); set for the control path by
#: ``--rt-priority`` and the launch argument ``rt_priority``.
RT_PRIORITY_ENV = "DCSMS_RT_PRIORITY"
#: Environment variable: the CPUs (a list as ``taskset -c`` takes it: ``1``, ``0,2-3``) a node
#: process's hot thread may run on (only it: :func:`dcsms_ros.ros.runtime.rt_cpus_from_env`);
#: set for the control path by ``--rt-cpus`` and the launch argument ``rt_cpus``. Unset: the
#: kernel places it.
RT_CPUS_ENV = "DCSMS_RT_CPUS"


def parse_cpus(text: str) -> frozenset[int]:
    """The CPUs of a list as ``taskset -c`` takes it (``"1"``, ``"0,2-3"``; ``""``: none).

    Raises
    ------
    ValueError
        A malformed list, with a message that names it.
    """
    cpus: set[int] = set()
    for item in (t.strip() for t in text.split(",")):
        if not item and not text.strip():
            continue
        lo, sep, hi = item.partition("-")
        try:
            first, last = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ValueError(f"{text!r}: not a CPU list such as 1 or 0,2-3") from None
        if first < 0 or last < first:
            raise ValueError(f"{text!r}: not a CPU list such as 1 or 0,2-3")
        cpus.update(range(first, last + 1))
    return frozenset(cpus)


def format_cpus(cpus: Collection[int]) -> str:
    """``cpus`` as :func:`parse_cpus` reads them (``""`` for none)."""
    return ",".join(str(c) for c in sorted(cpus))


#: Environment variables of a recorded run of one process per node (``dcsms up --record``):
#: the bag directory in which a node process records the per-sample topics it publishes
#: itself, and those topics (space-separated); :mod:`dcsms_ros.nodes.recorder_part`.
RECORD_PART_ENV = "DCSMS_RECORD_PART"
RECORD_TOPICS_ENV = "DCSMS_RECORD_TOPICS"
#: Writer history of lockstep streams (:func:`dcsms_ros.ros.qos.stream_pub`), and so the
#: reader history of a recorder of a lockstep run: how far a reliable observer (recorder,
#: probe) may lag behind, and the window in which a sample it lost (a full shared-memory queue
#: while its process was starved) can still be repaired, which takes a heartbeat period of the
#: writer (3 s in Fast DDS, 100 ms with the package's profile since 2026-11-28) plus the time
#: the starved reader needs: 25,000 samples are 5 s at the composed graph's 5 kHz. Measured
#: with 1,000 and 3 s heartbeats: a recorder on a loaded machine lost bursts of samples of a
#: composed run.
LOCKSTEP_WRITER_DEPTH = 25000


@dataclass(frozen=True)
class NodeSpec:
    """One node of the graph.

    Attributes
    ----------
    name : str
        Node name (in the graph's namespace).
    executable : str
        Console script of ``ros2 run dcsms_ros``; module ``dcsms_ros.nodes.<executable>``.
    params : mapping
        The node's own parameters (on top of the shared ones).
    control_path : bool
        On the per-sample path (plant, decoupling, controllers): ``--rt-priority`` applies.
    remappings : tuple of (from, to)
        ROS remappings of this node.
    """

    name: str
    executable: str
    params: Mapping[str, Any] = field(default_factory=dict)
    control_path: bool = False
    remappings: tuple[tuple[str, str], ...] = ()

    @property
    def module(self) -> str:
        """The Python module of the executable."""
        return f"dcsms_ros.nodes.{self.executable}"

    @property
    def node_class(self) -> str:
        """``module:Class`` of the node (composed deployment)."""
        return NODE_CLASSES[self.executable]


@dataclass(frozen=True)
class GraphSpec:
    """A graph: namespace, shared parameters and nodes (see :func:`define_graph`)."""

    namespace: str
    schedule: str
    num_stages: int
    shared: Mapping[str, Any]
    nodes: tuple[NodeSpec, ...]

    @property
    def names(self) -> topics.Names:
        """Topic and service names of this graph, absolute."""
        return topics.Names(self.namespace)

    def node(self, name: str) -> NodeSpec:
        """The node called ``name``.

        Raises
        ------
        KeyError
        """
        for n in self.nodes:
            if n.name == name:
                return n
        raise KeyError(name)

    def with_node(self, spec: NodeSpec) -> GraphSpec:
        """This graph with ``spec`` added (or replacing the node of the same name)."""
        rest = tuple(n for n in self.nodes if n.name != spec.name)
        return replace(self, nodes=(*rest, spec))

    def with_params(self, name: str, **params: Any) -> GraphSpec:
        """This graph with parameters of node ``name`` set (e.g. a benchmark's timing file)."""
        old = self.node(name)
        new = replace(old, params={**old.params, **params})
        return replace(self, nodes=tuple(new if n.name == name else n for n in self.nodes))

    def fqn(self, name: str) -> str:
        """Fully qualified name of node ``name`` (``/dcsms/plant_simulator``)."""
        return f"{self.namespace.rstrip('/')}/{name}"

    def params_document(self) -> dict[str, Any]:
        """The params file of the run: ``/**`` shared, then each node by its full name."""
        doc: dict[str, Any] = {"/**": {"ros__parameters": dict(self.shared)}}
        for n in self.nodes:
            if n.params:
                doc[self.fqn(n.name)] = {"ros__parameters": dict(n.params)}
        return doc

    def stream_topics(self) -> list[str]:
        """Every per-sample topic (absolute), for observers that must not miss a sample."""
        nm = self.names
        bodies = topics.body_names(self.num_stages)
        excited = any(n.name == topics.EXCITATION_ID for n in self.nodes)
        return ([nm.sensors_raw, nm.actuators_applied] + [nm.velocity(b) for b in bodies]
                + [nm.truth(b) for b in bodies]
                + [nm.force(c) for c in controller_ids(self.num_stages)]
                + ([nm.force(topics.EXCITATION_ID)] if excited else []))

    def recorded_observed(self, recorded: Collection[str] | None = None,
                          streams: bool = True) -> list[str]:
        """What the plant of a recorded run waits for the recorder to subscribe to before
        sample 0 (absolute; ``recorded``: the recorded topics, None: all): every per-sample
        topic (unless ``streams`` is False: the node processes record them themselves), and
        the latched mode and configuration, which keep only their newest message: a
        recorder that found them after a switch would miss the modes before it. Real time
        waits too (bounded by ``handshake_timeout_s``), so the bag starts at sample 0; once
        stepping, nothing waits on the recorder."""
        nm = self.names
        wanted = [*(self.stream_topics() if streams else []), nm.mode, nm.config]
        return [t for t in wanted if recorded is None or t in recorded]

    def analysis_topics(self) -> list[str]:
        """What ``dcsms analyze`` reads (absolute): recording only these keeps the graph fast
        (the plant skips its truth topics when nobody subscribes)."""
        nm = self.names
        return ([nm.velocity(b) for b in topics.body_names(self.num_stages)]
                + [nm.actuators_applied, nm.mode, nm.config, nm.supervisor_state])

    def to_dict(self) -> dict[str, Any]:
        """Plain data (YAML/JSON) of the spec; :func:`spec_from_dict` reads it back."""
        return {"namespace": self.namespace, "schedule": self.schedule,
                "num_stages": self.num_stages, "shared": dict(self.shared),
                "nodes": [{"name": n.name, "executable": n.executable, "params": dict(n.params),
                           "control_path": n.control_path,
                           "remappings": [list(r) for r in n.remappings]}
                          for n in self.nodes]}


def spec_from_dict(d: Mapping[str, Any]) -> GraphSpec:
    """Inverse of :meth:`GraphSpec.to_dict`."""
    nodes = tuple(NodeSpec(n["name"], n["executable"], dict(n.get("params", {})),
                           bool(n.get("control_path", False)),
                           tuple((str(a), str(b)) for a, b in n.get("remappings", [])))
                  for n in d["nodes"])
    return GraphSpec(str(d["namespace"]), str(d["schedule"]), int(d["num_stages"]),
                     dict(d["shared"]), nodes)


def shared_parameters(cfg: SystemConfig, schedule: str,
                      observers: Iterable[str] = ()) -> dict[str, Any]:
    """The parameters every node reads: the flat configuration and the schedule."""
    # empty arrays have no type in a params file; the nodes default them to empty anyway
    flat = {k: v for k, v in (cfg.params or {}).items() if not (isinstance(v, list) and not v)}
    flat["schedule"] = schedule
    obs = list(observers)
    if obs:  # every node with a stream publisher holds its first lockstep answer
        flat["wait_for_subscribers"] = obs
    return flat


def define_graph(cfg: SystemConfig, *, schedule: str = "realtime", mode: Mode = Mode.PASSIVE,
                 namespace: str = topics.NAMESPACE, duration_s: float = 0.0,
                 observers: Sequence[str] = (), ground_from: str = "", trip: bool = True,
                 allow_unstable: bool = False, hold_at_s: float = 0.0,
                 excite: Sequence[str] = (), excite_active: bool = True) -> GraphSpec:
    """The nodes of one table for ``cfg`` (N stages, 1dof/6dof).

    Parameters
    ----------
    cfg : SystemConfig
        Validated configuration (every node gets its flat parameters).
    schedule : {"realtime", "lockstep"}
    mode : Mode
        Initial mode: its controllers start enabled.
    namespace : str
        Namespace of every name of the graph (:func:`dcsms_ros.core.topics.check_namespace`).
    duration_s : float
        Simulated seconds after which the plant finishes (0: until stopped).
    observers : sequence of str
        Topics (absolute) that need a subscriber outside the graph before the first lockstep
        sample (a recorder, a probe).
    ground_from : str
        ``BAG[:TOPIC]`` whose ground velocity the plant replays ('' : white noise).
    trip : bool
        The mode switch runs the instability trip; in lockstep the plant then waits for its
        verdict at every checkpoint (``trip_gate``), so the trip lands on the batch engine's
        sample.
    allow_unstable : bool
        Let the mode switch and the controllers accept modes and tunings the model calls
        unstable (the trip is then the last line of defence).
    hold_at_s : float
        Lockstep: the plant stops before this simulated time until released (> 0; a mode
        schedule's first switch); 0: no hold.
    excite : sequence of str
        Excitation specifications (as ``dcsms sim --excite``): adds the ``excitation`` node,
        whose wrench the plant sums with the controllers' (and waits for in lockstep).
    excite_active : bool
        The excitation starts with the run (else its ``~/enable`` service starts it).
    """
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule must be one of {SCHEDULES}, got {schedule!r}")
    ns = topics.check_namespace(namespace)
    n = cfg.plant.num_stages
    on = enabled_controllers(mode, n)
    lockstep = schedule == "lockstep"
    # start order: the supervisor and the controllers first, the plant (which waits for them)
    # last
    # no node subscribes to /clock (use_sim_time stays false): timers and watchdogs run on the
    # steady clock and every stamp carries the sample time; /clock is for ROS tools. Each
    # /clock message woke every node's executor (~14 % of a core for mode_switch alone, and
    # composed, contention for the driver thread)
    nodes = [NodeSpec("mode_switch", "mode_switch", {
        "initial_mode": mode.value, "trip_enabled": bool(trip),
        "allow_unstable": bool(allow_unstable)})]
    for cid in controller_ids(n):
        p: dict[str, Any] = {"enabled": cid in on, "allow_unstable": bool(allow_unstable)}
        who = ControllerId.parse(cid)
        if who.feedback:
            p["stage"] = who.stage
        nodes.append(NodeSpec(cid, "feedback_controller" if who.feedback
                              else "feedforward_controller", p, control_path=True))
    nodes += [
        NodeSpec("sensor_decoupling", "sensor_decoupling", control_path=True),
        NodeSpec("plant_simulator", "plant_simulator", {
            "duration_s": float(duration_s), "ground_from": ground_from,
            "trip_gate": bool(trip and lockstep), "hold_at_s": float(hold_at_s),
            "excitation": bool(excite)}, control_path=True),
    ]
    if excite:  # before the plant, which waits for it like for a controller
        nodes.insert(-1, NodeSpec(topics.EXCITATION_ID, "excitation", {
            "spec": list(excite), "active": bool(excite_active),
            "duration_s": float(duration_s)}, control_path=True))
    return GraphSpec(ns, schedule, n, shared_parameters(cfg, schedule, observers), tuple(nodes))


__all__ = ["NODE_CLASSES", "RECORD_PART_ENV", "RECORD_TOPICS_ENV", "RT_CPUS_ENV", "RT_PRIORITY_ENV",
           "GraphSpec", "NodeSpec", "define_graph", "format_cpus", "parse_cpus",
           "shared_parameters", "spec_from_dict"]
