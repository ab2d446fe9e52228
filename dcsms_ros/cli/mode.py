"""``dcsms mode [NAME]``: switch the running graph's control mode, or show the current one.

``NAME`` is any spelling :func:`~dcsms_ros.core.modes.parse_mode` accepts (``DFBC+FFC``,
``dfbc_ffc``, ``fbc-ffc`` ...); an unknown name exits with status 2 and lists the valid ones.
The switch is the ``/dcsms/set_mode/<mode>`` service of the ``mode_switch`` node; its answer is
printed. Without NAME the current mode is printed, and the supervisor's state on a second line
(``supervisor: STATE MODE at T s: reason``). Exit status: 0 switched (or shown), 1 refused,
rolled back or no graph answering.
"""

from __future__ import annotations

import argparse
import os
import sys
from functools import partial
from typing import Any

from dcsms_ros.core import topics
from dcsms_ros.core.modes import parse_mode


def register(subparsers: Any) -> None:
    """Add the ``mode`` sub-command."""
    p = subparsers.add_parser(
        "mode", help="switch the running graph's control mode",
        description="Switch the running graph (dcsms up) to a control mode atomically: every "
        "controller involved confirms, or all are rolled back. Without NAME, print the current "
        "mode.")
    p.add_argument("name", nargs="?", default=None, metavar="NAME",
                   help="Passive, FBC, FFC, FBC+FFC, DFBC or DFBC+FFC (any case)")
    p.add_argument("--reset-trip", action="store_true",
                   help="clear a latched instability trip (before or instead of switching)")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the graph to answer (default 5)")
    p.set_defaults(func=run)


def _keep(into: list[str], msg: Any) -> None:
    into.append(msg.data)


#: A latched history has arrived once nothing new came for this long, s.
QUIET_S = 0.2


def _until_quiet(executor: Any, into: list[str]) -> None:
    """Spin until ``into`` stops growing for :data:`QUIET_S`."""
    from dcsms_ros.ros.context import spin_until  # noqa: PLC0415 - deferred: ROS

    while spin_until(executor, partial(_grown, into, len(into)), timeout_s=QUIET_S):
        pass


def _grown(into: list[str], seen: int) -> bool:
    return len(into) > seen


def run(args: argparse.Namespace) -> int:
    """Handler: call the service(s) and print the answer."""
    mode = parse_mode(args.name) if args.name is not None else None  # ModeError -> exit 2
    # deferred: `dcsms mode BAD` must fail fast, without ROS
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415 - deferred: ROS
    from rclpy.node import Node  # noqa: PLC0415 - deferred: ROS
    from std_msgs.msg import String  # noqa: PLC0415 - deferred: ROS
    from std_srvs.srv import Trigger  # noqa: PLC0415 - deferred: ROS

    from dcsms_ros.ros import qos  # noqa: PLC0415 - deferred: ROS
    from dcsms_ros.ros.context import (  # noqa: PLC0415 - deferred: ROS
        ros_context,
        spin_until,
    )

    calls = ([topics.RESET_TRIP] if args.reset_trip else []) + (
        [topics.set_mode_service(mode.value)] if mode is not None else [])
    # signals stay Python's: Ctrl-C raises KeyboardInterrupt (exit 130) through the block,
    # which still destroys the node and shuts the context down
    with ros_context([]) as ros:
        node = Node(f"dcsms_mode_{os.getpid()}", context=ros.context)
        executor = SingleThreadedExecutor(context=ros.context)
        executor.add_node(node)
        try:
            for name in calls:
                client = node.create_client(Trigger, name)
                if not client.wait_for_service(timeout_sec=args.timeout):
                    domain = os.environ.get("ROS_DOMAIN_ID", "0")
                    print(f"dcsms: error: service {name} not available after "
                          f"{args.timeout:g} s; is `dcsms up` running in "
                          f"ROS_DOMAIN_ID={domain}?", file=sys.stderr)
                    return 1
                future = client.call_async(Trigger.Request())
                spin_until(executor, future.done, timeout_s=args.timeout)
                result = future.result()
                if result is None:
                    print(f"dcsms: error: no answer from {name} within {args.timeout:g} s",
                          file=sys.stderr)
                    return 1
                print(result.message, flush=True)
                if not result.success:
                    return 1
            if not calls:
                got: list[str] = []
                state: list[str] = []
                for topic, into in ((topics.MODE, got), (topics.SUPERVISOR_STATE, state)):
                    node.create_subscription(String, topic, partial(_keep, into), qos.latched())
                if not spin_until(executor, lambda: bool(got), timeout_s=args.timeout):
                    print(f"dcsms: error: no mode on {topics.MODE} within {args.timeout:g} s; "
                          f"is `dcsms up` running?", file=sys.stderr)
                    return 1
                # both topics keep a history (events QoS): it arrives as a burst, and the
                # newest message is the answer, so read until the burst has ended
                _until_quiet(executor, got)
                print(got[-1])
                # both are latched by the same node: the state follows the mode at once
                if spin_until(executor, lambda: bool(state), timeout_s=min(args.timeout, 1.0)):
                    _until_quiet(executor, state)
                    print(f"supervisor: {state[-1]}")
            return 0
        finally:
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()


__all__ = ["register", "run"]
