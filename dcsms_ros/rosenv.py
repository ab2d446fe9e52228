"""The ROS environment of every process this package starts: discovery stays on this machine.

Jazzy's default discovery range (SUBNET) lets a test or a demo talk to every ROS graph on the
network. Every participant we create, and every child process we start, keeps discovery on
localhost unless the user chose a range; a rig spanning hosts sets
``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` itself (docs/graph.md).
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

#: The variable rmw reads, and the range we default to.
DISCOVERY_RANGE_VAR = "ROS_AUTOMATIC_DISCOVERY_RANGE"
DEFAULT_RANGE = "LOCALHOST"


def keep_discovery_local(env: MutableMapping[str, str] | None = None) -> None:
    """Set the discovery range to localhost in ``env`` (default: this process's environment)
    unless it is set already."""
    (os.environ if env is None else env).setdefault(DISCOVERY_RANGE_VAR, DEFAULT_RANGE)


__all__ = ["DEFAULT_RANGE", "DISCOVERY_RANGE_VAR", "keep_discovery_local"]
