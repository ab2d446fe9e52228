"""The stability guard: no switch or tuning the model of the running configuration calls
unstable, unless the graph allows it (parameter ``allow_unstable``).

Design: ``mode_switch`` holds the whole configuration. It declares every parameter, follows
the tuning changes made on the controller nodes through ``/parameter_events`` and republishes
the merged configuration on ``<ns>/config`` (transient local). It refuses a switch into a mode
whose loop has a pole on or outside the unit circle (:func:`dcsms_ros.core.loop_stability.
unstable_reason` names it), and a change of its own parameters that makes the active mode
unstable. Each controller knows only its own tuning; its guard listens to ``<ns>/config`` and
``<ns>/mode`` (both latched) and vets a change of its parameters against that configuration
with the change applied, in the active mode (on-set callback: rejected with the reason, nothing
changes). Until a controller has heard both it cannot judge and lets the change through;
changes made on two nodes at the same moment are each judged without the other. The
instability trip stays the last line of defence (``allow_unstable`` true: the guard only
logs).

In real time mode_switch's guard (its initial mode, a switch, a change of its parameters,
``control.input_timeout_s`` among them) also refuses a mode that a force as late as the plant
still applies it (``control.input_timeout_s``) would destabilise
(:func:`dcsms_ros.core.margins.late_force_reason`: one controller late, or all). The
controllers' own vet does not: it runs under their hot lock, and the delay margins of the
TEM's model take ~0.2 s (table1 ~0.04 s), a stall of the control path; ``dcsms model check``
and the next switch judge that.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rclpy.node import Node
from std_msgs.msg import String

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig, config_from_flat
from dcsms_ros.core.loop_stability import unstable_reason
from dcsms_ros.core.margins import late_force_reason
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.core.params_file import parse_params_text
from dcsms_ros.errors import DcsmsError
from dcsms_ros.ros import qos
from dcsms_ros.ros.params import declare_local


class StabilityGuard:
    """Judges modes and tunings of one node.

    Parameters
    ----------
    node : Node
        Declares ``allow_unstable`` on it; with ``listen`` subscribes to config and mode.
    listen : bool
        Learn the configuration and the mode from ``<ns>/config`` and ``<ns>/mode``
        (controllers); False: the owner sets :attr:`flat` and :attr:`mode` (mode_switch).
    late : bool
        Also refuse a mode that forces ``control.input_timeout_s`` late destabilise (real
        time).

    Attributes
    ----------
    allow : bool
        ``allow_unstable``: judge, log, but refuse nothing.
    flat : dict
        The whole configuration, by dotted name.
    mode : Mode or None
        The active mode.
    """

    def __init__(self, node: Node, listen: bool, late: bool = False) -> None:
        self.node = node
        self.late = late
        self.allow = bool(declare_local(node, "allow_unstable", False, "Accept switches and "
                                        "parameter changes the model calls unstable (the "
                                        "instability trip is then the last line of defence)"))
        self.flat: dict[str, Any] = {}
        self.mode: Mode | None = None
        if listen:
            node.create_subscription(String, topics.LOCAL.config, self._on_config,
                                     qos.latched())
            node.create_subscription(String, topics.LOCAL.mode, self._on_mode, qos.latched())

    def _on_config(self, msg: String) -> None:
        try:
            self.flat = parse_params_text(msg.data, topics.LOCAL.config)
        except DcsmsError as exc:
            self.node.get_logger().warning(f"ignoring {topics.LOCAL.config}: {exc}")

    def _on_mode(self, msg: String) -> None:
        try:
            self.mode = parse_mode(msg.data)
        except DcsmsError:
            self.mode = None

    def config(self, changes: Mapping[str, Any] | None = None) -> SystemConfig | None:
        """The whole configuration with ``changes`` applied (None if unknown or invalid)."""
        if not self.flat:
            return None
        try:
            return config_from_flat({**self.flat, **(changes or {})}, "stability guard")
        except DcsmsError:
            return None

    def refuse_mode(self, mode: Mode, cfg: SystemConfig | None = None) -> str | None:
        """The reason ``mode`` must not run with ``cfg`` (default :meth:`config`), or None."""
        cfg = cfg if cfg is not None else self.config()
        reason = unstable_reason(cfg, mode) if cfg is not None else None
        if reason is None and self.late and cfg is not None:
            reason = late_force_reason(cfg, mode)
        if reason is None:
            return None
        if self.allow:
            self.node.get_logger().warning(f"{reason}; allowed (allow_unstable)")
            return None
        return f"{reason}; refused (allow_unstable is false)"

    def vet(self, changes: Mapping[str, Any]) -> str | None:
        """On-set check of a node's parameter ``changes``: the reason to reject, or None."""
        if self.mode is None or self.mode is Mode.PASSIVE:
            return None
        cfg = self.config(changes)
        if cfg is None:
            return None  # not known yet, or the node's own validation rejects the values
        return self.refuse_mode(self.mode, cfg)


__all__ = ["StabilityGuard"]
