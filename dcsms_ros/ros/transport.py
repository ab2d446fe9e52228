"""How an observer process (the recorder) receives: UDP loopback, never shared memory.

Fast DDS delivers between processes of one host through shared-memory ports, and every writer
to a port shares its locks and its health checks with the port's reader: Fast DDS 2.14's
``SharedMemGlobal::Port`` takes an interprocess mutex on each push, and a writer that (re)opens
a port whose listener has not reported for a while sleeps ``healthy_check_timeout_ms / 3`` =
333 ms in a health check, while holding its participant's send lock: through either path a
SCHED_FIFO writer (the plant's hot thread) can wait for a descheduled observer. Over UDP a slow
reader only loses datagrams, which the recorder counts; a writer shares nothing with it.

Measured (docs/performance.md, recorded real-time runs, one process per node): the plant
stalled ~333 ms in 1 of 10 runs either way in a same-session A/B; pooled over two days, 10 of 42
runs with shared memory against 4 of 60 over UDP, a difference the day confounds. With UDP, 5 of
7 recorder losses of >= 14,000 messages came without a plant stall (shared memory: 3 of 9). The
cost is in the writers: the plant's CPU per sample with recording on is 1.23x that with it off
(``make bench``; 1.05x before).

rmw_fastrtps builds its own transports under ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (SHM
and UDP; ``FASTDDS_BUILTIN_TRANSPORTS`` is ignored), but it takes a DataReader's locators from
the default XML profile. :func:`observe_over_udp` points Fast DDS at ``observer_profile.xml``,
whose default reader listens on 127.0.0.1 only. It does nothing when the user has a profile
file of their own, or chose a discovery range beyond this host (a reader on 127.0.0.1 cannot
hear another host).
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

from dcsms_ros.rosenv import DEFAULT_RANGE, DISCOVERY_RANGE_VAR

#: The variables Fast DDS reads its XML profiles from (the first one set wins).
PROFILES_VARS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
#: The observer's profile, installed with the package.
OBSERVER_PROFILE = Path(__file__).with_name("observer_profile.xml")


def observe_over_udp(env: MutableMapping[str, str] | None = None) -> bool:
    """Make the DDS readers of this process (``env``: its environment) receive over UDP
    loopback; call before ``rclpy.init``. True if the profile was set, False if the user's
    profile file or discovery range takes precedence."""
    env = os.environ if env is None else env
    if any(env.get(v) for v in PROFILES_VARS):
        return False
    if env.get(DISCOVERY_RANGE_VAR, DEFAULT_RANGE) != DEFAULT_RANGE:
        return False
    env[PROFILES_VARS[1]] = str(OBSERVER_PROFILE)
    return True


__all__ = ["OBSERVER_PROFILE", "PROFILES_VARS", "observe_over_udp"]
