"""QoS profiles of the graph, each chosen on purpose.

Publishers are always *reliable*: a reliable writer matches both reliable and best-effort
readers, so the recorder (reliable, to lose nothing) and the control loop can subscribe to the
same stream. What differs between the two schedules is the readers of the control path:

* **lockstep** - at most one sample per topic is in flight in the loop itself, and a lost
  sample cannot desynchronise it: the plant republishes a sample whose replies are missing
  after ``lockstep_retry_s`` and every node answers a repeated stamp from its cache. Loop
  readers are therefore *best-effort* keep-last :data:`LOCKSTEP_DEPTH`: on the shared-memory
  loopback nothing is lost in practice, and each hop saves the reliable protocol's heartbeat
  and acknack exchange, which costs about as much CPU as the sample itself (measured: rclpy
  ping-pong 4,900 vs 3,200 round trips/s, ~half the CPU per round trip; README
  "Performance"). The writers stay reliable and keep :data:`LOCKSTEP_WRITER_DEPTH` samples so
  a slower reliable observer (recorder, test probe) can fall behind by that many without losing
  one, while the loop never waits for it (keep-last writers never block).
* **real time** - the newest sample is the only useful one; a backlog would add latency to
  every later sample. Control-path readers are best-effort keep-last 1 (the ROS
  ``sensor_data`` profile): a late callback processes the freshest sample and the skipped ones
  are gone, as on a real-time controller that misses a deadline. Writers keep
  :data:`REALTIME_DEPTH` samples for reliable observers.
* **latched state** (``/dcsms/mode``, ``/dcsms/config``) - reliable, transient local, depth 1:
  a late joiner (``dcsms mode``, a recorder, a restarted node) gets the current value at once.
"""

from __future__ import annotations

import os

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dcsms_ros.graph import LOCKSTEP_WRITER_DEPTH

#: Reader history of lockstep loop streams.
LOCKSTEP_DEPTH = 1000
#: Writer history of real-time streams for reliable observers: 4 s at 2 kHz, so a recorder
#: starved of CPU for seconds on a loaded machine loses nothing (the reliability soak measured
#: 100 samples = 50 ms losing ~7 % and 2000 losing ~2 %). Keep-last writers never block, and the
#: control path reads best-effort keep-last 1, so this costs memory only (~1 MB per topic).
REALTIME_DEPTH = 8000


def latched() -> QoSProfile:
    """Reliable, transient local, keep-last 1: current mode and configuration."""
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def stream_pub(lockstep: bool, durable: bool = False) -> QoSProfile:
    """Writer of a per-sample stream (sensors, velocities, forces, applied, truth); also the
    profile of an observer that must see every sample it can (mode_switch, a recorder).

    ``durable`` (lockstep only): transient local, so a reader that matched late still gets the
    history from sample 0 (the trip checker of mode_switch must see every sample)."""
    rt_reliable = os.environ.get("DCSMS_RT_RELIABLE") == "1"  # A/B measurement only
    return QoSProfile(depth=LOCKSTEP_WRITER_DEPTH if lockstep else REALTIME_DEPTH,
                      history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE if lockstep or rt_reliable
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if lockstep and durable
                      else DurabilityPolicy.VOLATILE)


def stream_sub(lockstep: bool) -> QoSProfile:
    """Reader of a per-sample stream on the control path (see the module notes)."""
    return QoSProfile(depth=LOCKSTEP_DEPTH if lockstep else 1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def status() -> QoSProfile:
    """Diagnostics: reliable keep-last 10, volatile (a periodic report; old ones are moot)."""
    return QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


#: /clock: reliable keep-last 1 would block nobody; rclpy's time source subscribes with
#: keep-last 1 best-effort-compatible QoS, so only the newest clock matters.
def clock() -> QoSProfile:
    """Writer of ``/clock``: reliable keep-last 1 (readers only need the newest time)."""
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
