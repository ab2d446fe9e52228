"""How the package's processes reach each other: UDP loopback, never Fast DDS shared memory.

Fast DDS (2.14, under rmw_fastrtps) opens a reader's shared-memory port lazily, at a writer
participant's first send to it, and checks the port's health first: if the port's listener is
waiting and a watchdog verified it since it last woke, the check sleeps
``healthy_check_timeout_ms / 3`` = 333 ms and tries again. The sending thread does that inside
``RTPSParticipantImpl::sendSync``, which holds the participant's one send mutex, so every other
publish of that process can wait too: the plant's SCHED_FIFO hot thread was caught blocked
250-345 ms inside ``publish``. First sends come from Fast DDS's discovery and event threads as
participants and endpoints are matched, i.e. mostly in a run's first seconds, which is where
every stall of the plant was seen.

Measured with ``perf trace`` on the user's recorded per-process command (docs/performance.md):
with shared memory, 2-6 such 333 ms sleeps per run in Fast DDS threads of several processes
(the plant, the decoupling, a controller, mode_switch, the recorder, ``dcsms up``), most during
discovery, some after the first sample; keeping only the supervisor and ``dcsms mode`` off
shared memory still left them, and one run of seven stalled. With every process on UDP: none in
14 runs, and no process maps a shared-memory segment. The price, paired runs on this 2-core
machine: control latency p50 1.2 ms instead of 0.75, the plant's and the decoupling's CPU per
sample 1.1x and 1.2x, and a per-process recorder (nice +10, 22,000 messages/s) keeps about half
of the messages instead of nearly all; the composed graph, whose recorder takes the bytes in
the process, is not affected.

rmw_fastrtps builds its own transports under ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (shared
memory and UDP; ``FASTDDS_BUILTIN_TRANSPORTS`` is ignored), but it takes a participant's default
unicast locators from the default XML profile. :func:`loopback_over_udp` points Fast DDS at
``loopback_profile.xml``, whose participant announces 127.0.0.1 over UDP only; every process
sets it through :func:`dcsms_ros.ros.context.ros_context`. It does nothing when the user has a
profile file of their own, or chose a discovery range beyond this host (an endpoint on
127.0.0.1 cannot be reached from another host). A tool outside the package (``ros2 topic echo``
with the defaults) announces shared memory, and a writer of ours then sends to it through its
port: start such a tool with ``FASTRTPS_DEFAULT_PROFILES_FILE`` set to :data:`PROFILE`
(docs/graph.md).
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

from dcsms_ros.rosenv import DEFAULT_RANGE, DISCOVERY_RANGE_VAR

#: The variables Fast DDS reads its XML profiles from (the first one set wins).
PROFILES_VARS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
#: The package's participant profile, installed with it.
PROFILE = Path(__file__).with_name("loopback_profile.xml")


def loopback_over_udp(env: MutableMapping[str, str] | None = None) -> bool:
    """Make the DDS participants of a process (``env``: its environment) announce UDP loopback
    only; call before the first participant exists (Fast DDS reads the profile once per
    process). True if the profile was set, False if the user's profile file or discovery range
    takes precedence."""
    env = os.environ if env is None else env
    if any(env.get(v) for v in PROFILES_VARS):
        return False
    if env.get(DISCOVERY_RANGE_VAR, DEFAULT_RANGE) != DEFAULT_RANGE:
        return False
    env[PROFILES_VARS[1]] = str(PROFILE)
    return True


__all__ = ["PROFILE", "PROFILES_VARS", "loopback_over_udp"]
