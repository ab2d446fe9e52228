"""QoS profiles of the graph, each chosen on purpose.

What differs between the two schedules:

* **lockstep** - at most one sample per topic is in flight in the loop itself, and a lost
  sample cannot desynchronise it: the plant republishes a sample whose replies are missing
  after ``lockstep_retry_s`` and every node answers a repeated stamp from its cache. Writers
  are *reliable* (a reliable writer matches reliable and best-effort readers) and keep
  :data:`LOCKSTEP_WRITER_DEPTH` samples, so an observer (recorder, test probe, mode_switch's
  trip) gets every sample; the loop waits for the slowest reader anyway. Loop readers are
  *best-effort* keep-last :data:`LOCKSTEP_DEPTH`: on the shared-memory loopback nothing is
  lost in practice, and each hop saves the reliable protocol's heartbeat and acknack exchange,
  which costs about as much CPU as the sample itself (measured: rclpy ping-pong 4,900 vs 3,200
  round trips/s, ~half the CPU per round trip; README "Performance").
* **real time** - the newest sample is the only useful one, and the control path must never
  wait on an observer. Writers and readers are *best-effort*: a late callback processes the
  freshest sample and the skipped ones are gone, as on a real-time controller that misses a
  deadline; an observer that falls behind (a recorder starved of CPU, a stopped
  ``ros2 topic echo``) loses samples and counts them as stamp gaps (the recorder's report, the
  run's summary line) instead of holding the writer's history and its retransmissions.
  Measured (docs/performance.md, issue 21): fewer late samples in each of 7 alternating
  pairs of recorded 20 s real-time runs on the shared 2-core machine (best-effort against
  reliable: per process 4.7-5.3 % against 7.8-16.3 %; composed 1.9-4.9 % against 4.6-13.6 %;
  composed with the recorder stopped for 5 s 6.1-12.4 % against 15.7-17.6 %). Control-path
  readers are keep-last 1 (the ROS
  ``sensor_data`` profile), except the decoupling's, which must read every measurement
  (:func:`every_sample_sub`); observers keep :data:`REALTIME_DEPTH`.
* **latched state** (``/dcsms/config``) - reliable, transient local, depth 1: a late joiner
  (a recorder, a restarted node) gets the current value at once. **Events** (``/dcsms/mode``,
  ``/dcsms/supervisor/state``) keep :data:`EVENT_DEPTH`: every change reaches a recorder.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dcsms_ros.graph import LOCKSTEP_WRITER_DEPTH

#: Reader history of lockstep loop streams.
LOCKSTEP_DEPTH = 1000
#: History of real-time streams: an observer's reader queue (4 s at 2 kHz), so one starved of CPU
#: for a while loses nothing while its DDS thread still runs (the writer's history is unused:
#: best-effort writers do not retransmit).
REALTIME_DEPTH = 8000


def latched() -> QoSProfile:
    """Reliable, transient local, keep-last 1: current mode and configuration."""
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


#: Writer history of the event topics (mode, supervisor state): reliable keep-last 1 may replace a
#: message its reader has not acknowledged yet, and two transitions 50 ms of plant time apart
#: (RECOVERING -> ENGAGED -> RIDE_THROUGH) come closer than that in lockstep: one went missing
#: from the bag in 2 of 3 runs of test_graph_gives_up_on_an_unstable_loop_like_the_batch_engine.
EVENT_DEPTH = 100


def events() -> QoSProfile:
    """Reliable, transient local, keep-last :data:`EVENT_DEPTH`: every mode change and
    supervisor transition reaches each reader (a recorder); a late joiner gets the recent ones,
    the newest last (the current value)."""
    return QoSProfile(depth=EVENT_DEPTH, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def stream_pub(lockstep: bool, durable: bool = False) -> QoSProfile:
    """Writer of a per-sample stream (sensors, velocities, forces, applied, truth); also the
    profile of an observer that must see every sample it can (mode_switch, a recorder).

    ``durable`` (lockstep only): transient local, so a reader that matched late still gets the
    history from sample 0 (the trip checker of mode_switch must see every sample)."""
    return QoSProfile(depth=LOCKSTEP_WRITER_DEPTH if lockstep else REALTIME_DEPTH,
                      history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE if lockstep
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if lockstep and durable
                      else DurabilityPolicy.VOLATILE)


def stream_sub(lockstep: bool) -> QoSProfile:
    """Reader of a per-sample stream on the control path (see the module notes)."""
    return QoSProfile(depth=LOCKSTEP_DEPTH if lockstep else 1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


#: Real-time reader history of a control-path node that must read every sample (the
#: decoupling): 400 samples, 0.2 s at 2 kHz, longer than the stalls one process per node
#: showed on 2 cores (control latency p99 42-106 ms).
EVERY_SAMPLE_DEPTH = 400


def every_sample_sub(lockstep: bool) -> QoSProfile:
    """Reader of a per-sample stream whose every sample changes the reader's state: the
    decoupling's low-frequency extension inverts the geophones' roll-off (up to 81x below
    0.5 Hz for table1's 4.5 Hz geophones), so a skipped measurement is an error it integrates
    (``test/core/test_skipped_samples.py``: in the batch model 14 % of raw samples skipped
    in bursts raised table1's DFBC+FFC stage velocities 5x, as many controller inputs
    skipped 1.1x). Best-effort (never waits on the writer), keep-last
    :data:`EVERY_SAMPLE_DEPTH` in real time."""
    return QoSProfile(depth=LOCKSTEP_DEPTH if lockstep else EVERY_SAMPLE_DEPTH,
                      history=HistoryPolicy.KEEP_LAST,
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
