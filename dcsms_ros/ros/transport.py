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
sample 1.1x and 1.2x, and a per-process recorder (nice +10, 22,000 messages/s) kept about half
of the messages instead of nearly all on that (slow) day, all of them on a faster one; a
composed graph records inside the process by default and does not pay it.

rmw_fastrtps builds its own transports under ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (shared
memory and UDP; ``FASTDDS_BUILTIN_TRANSPORTS`` is ignored), but it takes a participant's default
unicast locators from the default XML profile. :func:`loopback_over_udp` points Fast DDS at
``loopback_profile.xml``, whose participant announces 127.0.0.1 over UDP only (and announces
itself every 200 ms for its first 4 s, then every second: see the file); every process
sets it through :func:`dcsms_ros.ros.context.ros_context`. It does nothing when the user has a
profile file of their own, or chose a discovery range beyond this host (an endpoint on
127.0.0.1 cannot be reached from another host). A tool outside the package (``ros2 topic echo``
with the defaults) announces shared memory, and a writer of ours then sends to it through its
port: start such a tool with ``FASTRTPS_DEFAULT_PROFILES_FILE`` set to :data:`PROFILE`
(docs/graph.md).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator, MutableMapping
from contextlib import contextmanager
from pathlib import Path

from dcsms_ros.rosenv import DEFAULT_RANGE, DISCOVERY_RANGE_VAR

#: The variables Fast DDS reads its XML profiles from (the first one set wins).
PROFILES_VARS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
#: Receive buffer (bytes) a recorder asks for on each of its UDP sockets (Linux doubles it).
RECORDER_RCVBUF_BYTES = 4 * 1024 * 1024
#: Linux's SO_RCVBUFFORCE (not in Python's socket module): a size above net.core.rmem_max,
#: allowed with CAP_NET_ADMIN.
_SO_RCVBUFFORCE = 33
#: The package's participant profile, installed with it.
PROFILE = Path(__file__).with_name("loopback_profile.xml")


@contextmanager
def loopback_over_udp(env: MutableMapping[str, str] | None = None) -> Iterator[bool]:
    """Point Fast DDS at :data:`PROFILE` while the block creates the process's first
    participant (rmw_fastrtps creates it with the first node, and Fast DDS reads the profile
    once per process); ``env``: the process's environment. Yields True if the profile was set,
    False if the user's profile file or discovery range takes precedence. The variable is
    removed again when the block ends, so a process started afterwards (another host's range,
    a test's own profile) chooses for itself."""
    env = os.environ if env is None else env
    if any(env.get(v) for v in PROFILES_VARS) or \
            env.get(DISCOVERY_RANGE_VAR, DEFAULT_RANGE) != DEFAULT_RANGE:
        yield False
        return
    env[PROFILES_VARS[1]] = str(PROFILE)
    try:
        yield True
    finally:
        env.pop(PROFILES_VARS[1], None)


def widen_udp_receive_buffers(size: int = RECORDER_RCVBUF_BYTES) -> list[int]:
    """Ask for ``size`` bytes of kernel receive buffer on every UDP socket of this process.

    Fast DDS sizes its sockets from ``net.core.rmem_default`` (212,992 bytes here: ~35 ms of
    the soak test's three recorded streams) and rmw offers no setting for it under
    ``LOCALHOST``; a recorder that loses its core for longer loses datagrams (the soak test
    lost 116-131 per stream in a loaded fresh-clone CI). Call once the process's participant
    exists. Without CAP_NET_ADMIN the kernel caps the size at ``net.core.rmem_max``.

    Returns
    -------
    list of int
        The buffer each UDP socket has now, bytes (Linux reports twice the size asked for).
    """
    sizes = []
    for name in os.listdir("/proc/self/fd"):
        try:
            fd = os.dup(int(name))
        except OSError:  # gone (the listing's own descriptor)
            continue
        try:
            s = socket.socket(fileno=fd)
        except OSError:  # not a socket
            os.close(fd)
            continue
        with s:
            if s.type != socket.SOCK_DGRAM or s.family not in (socket.AF_INET, socket.AF_INET6):
                continue
            try:
                s.setsockopt(socket.SOL_SOCKET, _SO_RCVBUFFORCE, size)
            except PermissionError:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
            sizes.append(s.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    return sizes


__all__ = ["PROFILE", "PROFILES_VARS", "RECORDER_RCVBUF_BYTES", "loopback_over_udp",
           "widen_udp_receive_buffers"]
