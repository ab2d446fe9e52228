"""ROS parameters <-> the core's :class:`~dcsms_ros.core.config.SystemConfig`.

Every node declares the *structure* of the system (``plant.*``, ``sensors.*``, ``actuators.*``
and the stage and body geometry): the core objects it steps read them (channel layout, reference
points, allocation, sample rate), and 6-DOF validation needs the whole geometry. On top of that a
node declares only the names it uses (:data:`SELECTORS`). Names it does not declare take the
schema defaults in its :class:`SystemConfig`; it never reads them.

Descriptors come from :mod:`dcsms_ros.core.schema`: description with the SI unit, numeric range
where both bounds are finite, read-only for everything except controller tuning and timeouts
(``feedback.*``, ``feedforward.*``, ``control.*``). A set-parameters request is validated by
building a new config with :func:`~dcsms_ros.core.config.config_from_flat`; it is rejected with
that error as the reason, and nothing changes (the validation does not hold the node's hot
loop). Accepted changes reach the node through its ``on_change(cfg, changed_names)`` after the
values are stored, under its hot-path lock (:mod:`.serialized`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from contextlib import nullcontext
from typing import Any, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterUninitializedException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from dcsms_ros.core.config import SystemConfig, config_from_flat
from dcsms_ros.core.schema import GLOBAL_SPECS, ParamSpec, expand_specs
from dcsms_ros.errors import ConfigError
from dcsms_ros.graph import SCHEDULES
from dcsms_ros.protocols.responder import Answerer
from dcsms_ros.ros.connectivity import publishers_matched
from dcsms_ros.ros.intraprocess import SamplePublisher
from dcsms_ros.ros.serialized import hot_lock

#: Prefixes of run-time tunable names; everything else is fixed once a node runs.
MUTABLE_PREFIXES = ("feedback.", "feedforward.", "control.", "supervisor.")
#: Prefixes that are not structure (declared only by the nodes that select them).
_NON_STRUCTURE = ("feedback.", "feedforward.", "control.", "disturbance.", "supervisor.")
T = TypeVar("T")

_TYPES = {
    "float": (ParameterType.PARAMETER_DOUBLE, Parameter.Type.DOUBLE),
    "int": (ParameterType.PARAMETER_INTEGER, Parameter.Type.INTEGER),
    "bool": (ParameterType.PARAMETER_BOOL, Parameter.Type.BOOL),
    "str": (ParameterType.PARAMETER_STRING, Parameter.Type.STRING),
    "floats": (ParameterType.PARAMETER_DOUBLE_ARRAY, Parameter.Type.DOUBLE_ARRAY),
    "ints": (ParameterType.PARAMETER_INTEGER_ARRAY, Parameter.Type.INTEGER_ARRAY),
}


def is_structure(name: str) -> bool:
    """True for names every node declares (topology, geometry, sensors, actuators, rate)."""
    return not name.startswith(_NON_STRUCTURE)


def _plant_select(name: str) -> bool:
    return name.startswith("disturbance.") or name in ("control.input_timeout_s",
                                                       "control.lockstep_timeout_s")


def feedback_select(stage: int) -> Callable[[str], bool]:
    """Selector of a stage-``stage`` feedback node: its own tuning, fade and timeouts."""
    prefix = f"feedback.stage{stage}."
    return lambda n: n.startswith(prefix) or n in ("control.fade_time_s",
                                                   "control.input_timeout_s")


#: What each node declares beyond the structure.
SELECTORS: dict[str, Callable[[str], bool]] = {
    "plant_simulator": _plant_select,
    "sensor_decoupling": lambda n: n == "control.input_timeout_s",
    "feedforward_controller": lambda n: n.startswith("feedforward.") or n in (
        "control.fade_time_s", "control.input_timeout_s"),
    # the supervisor publishes the whole configuration on /dcsms/config, so it declares all
    "mode_switch": lambda n: True,
}


def descriptor(spec: ParamSpec, read_only: bool) -> ParameterDescriptor:
    """A ParameterDescriptor for one schema entry (description, unit, range, read-only)."""
    rtype, _ = _TYPES[spec.kind]
    d = ParameterDescriptor(type=rtype, read_only=read_only)
    unit = "" if spec.unit == "-" else f" [{spec.unit}]"
    d.description = f"{spec.doc}{unit}"
    constraints = []
    finite = math.isfinite(spec.lo) and math.isfinite(spec.hi)
    if spec.kind in ("float", "floats", "int", "ints") and (
            math.isfinite(spec.lo) or math.isfinite(spec.hi)):
        lo = "(" if spec.lo_open else "["
        constraints.append(f"{'each value ' if spec.kind.endswith('s') else ''}in "
                           f"{lo}{spec.lo:g}, {spec.hi:g}]")
    if spec.length > 0:
        constraints.append(f"exactly {spec.length} values")
    elif spec.length == -3:
        constraints.append("x y z triples")
    if spec.choices:
        constraints.append("one of " + ", ".join(spec.choices))
    d.additional_constraints = "; ".join(constraints)
    # ranges are enforced by rclpy for scalars only; arrays are checked by config_from_flat
    if finite and spec.kind == "float":
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.lo),
                                                     to_value=float(spec.hi), step=0.0)]
    elif finite and spec.kind == "int":
        d.integer_range = [IntegerRange(from_value=int(spec.lo), to_value=int(spec.hi), step=1)]
    return d


def _plain(value: Any) -> Any:
    """rclpy returns arrays as array.array or numpy; the core wants lists."""
    if isinstance(value, (str, bool, int, float)) or value is None:
        return value
    return list(value)


def declare_spec(node: Node, spec: ParamSpec, read_only: bool) -> Any:
    """Declare one schema parameter and return its value (None when unset and no default)."""
    _, ptype = _TYPES[spec.kind]
    default = spec.default
    value: Any = ptype if isinstance(default, list) and not default else default
    if spec.kind == "float":
        value = float(default)
    elif spec.kind == "floats" and default:
        value = [float(x) for x in default]
    try:
        node.declare_parameter(spec.name, value, descriptor(spec, read_only))
        return _plain(node.get_parameter(spec.name).value)
    except ParameterUninitializedException:
        return None
    except InvalidParameterTypeException as exc:
        raise ConfigError(f"node {node.get_name()}: parameter '{spec.name}': {exc.args[0]}"
                          f" (floating-point values need a decimal point, e.g. 2000.0)") from None
    except InvalidParameterValueException as exc:
        raise ConfigError(f"node {node.get_name()}: parameter '{spec.name}': "
                          f"{exc.args[-1] if exc.args else exc}") from None


class NodeConfig:
    """The parameters a node declared, the config built from them, and live validation.

    Parameters
    ----------
    node : Node
    select : callable
        ``select(name) -> bool``: non-structure names this node uses.
    on_change : callable, optional
        ``on_change(cfg, changed)`` after an accepted set; ``changed`` is a set of names.

    Attributes
    ----------
    cfg : SystemConfig
        The current configuration (``source`` names the node).
    flat : dict
        The declared values that are set, by dotted name.
    """

    def __init__(self, node: Node, select: Callable[[str], bool],
                 on_change: Callable[[SystemConfig, set[str]], None] | None = None) -> None:
        self.node = node
        self.on_change = on_change
        self.source = f"node {node.get_fully_qualified_name()}"
        self.flat: dict[str, Any] = {}
        first = {s.name: s for s in GLOBAL_SPECS if s.name in ("plant.fidelity",
                                                               "plant.num_stages")}
        for spec in first.values():
            self.flat[spec.name] = declare_spec(node, spec, read_only=True)
        specs = expand_specs(int(self.flat["plant.num_stages"]))
        fidelity = self.flat["plant.fidelity"]
        self.names = set(first)
        for name, spec in specs.items():
            if name in first or (spec.fidelity and spec.fidelity != fidelity):
                continue
            if not (is_structure(name) or select(name)):
                continue
            value = declare_spec(node, spec, read_only=not name.startswith(MUTABLE_PREFIXES))
            self.names.add(name)
            if value is not None:
                self.flat[name] = value
        self.cfg = config_from_flat(self.flat, self.source)
        #: Optional extra on-set check of the changed values: the reason to reject, or None
        #: (the stability guard, :mod:`.stability`).
        self.vet: Callable[[dict[str, Any]], str | None] | None = None
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._applied)

    def _candidate(self, params: Iterable[Parameter]) -> tuple[dict[str, Any], set[str]]:
        flat = dict(self.flat)
        changed = set()
        for p in params:
            if p.name in self.names:
                flat[p.name] = _plain(p.value)
                changed.add(p.name)
        return flat, changed

    def _validate(self, params: list[Parameter]) -> SetParametersResult:
        flat, changed = self._candidate(params)
        if not changed:
            return SetParametersResult(successful=True)
        try:
            config_from_flat(flat, self.source)
            reason = self.vet({n: flat[n] for n in changed}) if self.vet is not None else None
        except ConfigError as exc:
            reason = str(exc)
        if reason is not None:
            self.node.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _applied(self, params: list[Parameter]) -> None:
        flat, changed = self._candidate(params)
        if not changed:
            return
        # the node's hot loop reads what on_change replaces: one at a time with it
        lock = hot_lock(self.node)
        with lock if lock is not None else nullcontext():
            self._apply(flat, changed)

    def _apply(self, flat: dict[str, Any], changed: set[str]) -> None:
        self.flat = flat
        self.cfg = config_from_flat(flat, self.source)
        self.node.get_logger().info("parameters changed: " + ", ".join(
            f"{n}={flat[n]}" for n in sorted(changed)))
        if self.on_change is not None:
            self.on_change(self.cfg, changed)


def add_post_set(node: Node, fn: Callable[[list[Parameter]], None]) -> None:
    """Register ``fn`` as a post-set parameters callback of ``node`` that runs under the node's
    hot-path lock (:func:`.serialized.hot_lock`), one at a time with its hot loop, like every
    other callback of the node: node code never locks."""
    def serialized(params: list[Parameter]) -> None:
        lock = hot_lock(node)
        with lock if lock is not None else nullcontext():
            fn(params)

    node.add_post_set_parameters_callback(serialized)


def declare_local(node: Node, name: str, default: Any, description: str,
                  read_only: bool = True, lo: float | None = None,
                  hi: float | None = None) -> Any:
    """Declare a node-specific (non-schema) parameter and return its value.

    ``default`` may be a :class:`rclpy.parameter.Parameter.Type` to declare an array that is
    empty unless set; its value is then ``[]``.
    """
    d = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if isinstance(default, float):
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
        elif isinstance(default, int) and not isinstance(default, bool):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
    try:
        node.declare_parameter(name, default, d)
        return _plain(node.get_parameter(name).value)
    except ParameterUninitializedException:
        return []
    except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
        raise ConfigError(f"node {node.get_name()}: parameter '{name}': "
                          f"{exc.args[-1] if exc.args else exc}") from None


def declare_schedule(node: Node) -> str:
    """Declare ``schedule`` (``lockstep`` | ``realtime``, default realtime) and return it."""
    value = declare_local(node, "schedule", "realtime", "Time schedule: lockstep (deterministic, "
                          "the plant waits for every controller) or realtime (wall clock)")
    if value not in SCHEDULES:
        raise ConfigError(f"node {node.get_name()}: schedule must be lockstep or realtime, got "
                          f"{value!r}")
    return str(value)


def declare_observed(node: Node) -> list[str]:
    """Declare ``wait_for_subscribers``: topics an observer outside the graph (recorder, probe)
    must be receiving before the first lockstep sample is answered."""
    return list(declare_local(node, "wait_for_subscribers", Parameter.Type.STRING_ARRAY,
                              "Topics that need a subscriber outside the graph (recorder, "
                              "probe) before the first lockstep sample"))


def answerer(node: Node, publish: Callable[[T], None], lockstep: bool,
             pubs: Sequence[SamplePublisher], observed: list[str]) -> Answerer[T]:
    """The per-sample :class:`~dcsms_ros.protocols.responder.Answerer` of ``node``: in
    lockstep its first answer waits until ``pubs`` matched every reader this node sees (and
    ``observed`` topics an observer), so an observer misses nothing (the plant retransmits)."""
    return Answerer(publish, lockstep, lambda: publishers_matched(node, pubs, observed),
                    on_timeout=lambda: node.get_logger().warning(
                        "not every reader matched; answering anyway"))
