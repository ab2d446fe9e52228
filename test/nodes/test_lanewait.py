"""A hot loop's wait on host lanes (real FIFOs and pipes, no ROS): which wait, kept how long."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from dcsms_ros.ros.hostlane import LaneReader, LaneWriter
from dcsms_ros.ros.laneinput import DDS, LANES, MIXED, STATE_S
from dcsms_ros.ros.lanewait import DDS_POLL_S, LaneWait

TOPIC = "/dcsms/velocity/stage1"


class _Path:
    """A hot path whose lane state the test sets, over a real lane."""

    def __init__(self, reader: LaneReader | None) -> None:
        self.reader, self.state, self.asked = reader, DDS, 0

    def lane_fds(self) -> list[int]:
        return [self.reader.fd] if self.reader is not None else []

    def lane_state(self, now: float) -> str:
        self.asked += 1
        return self.state


@pytest.fixture
def lane(tmp_path: Path):
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")
    yield r
    r.close()


def test_a_dds_wait_is_judged_again_at_once_a_lanes_wait_is_kept_for_state_s(lane):
    path = _Path(lane)
    w = LaneWait([path], serving=1)
    assert w.mode() == DDS and not w.wait(1.0)  # no wait: the loop waits on DDS
    path.state = LANES  # a writer said hello
    assert w.mode() == LANES  # at the next wake-up, not STATE_S later
    path.state, asked = MIXED, path.asked
    assert w.mode() == LANES and path.asked == asked  # kept, not asked
    time.sleep(1.5 * STATE_S)
    assert w.mode() == MIXED
    w.close()


def test_a_served_path_without_lanes_keeps_the_loop_on_dds(lane):
    path = _Path(lane)
    path.state = LANES
    w = LaneWait([path, _Path(None)], serving=2)
    assert w.paths == [path] and w.mode() == DDS and not w.wait(1.0)
    w.close()
    none = LaneWait([_Path(None)], serving=1)
    assert not none  # nothing to wait on
    none.close()


def test_a_loop_without_lanes_sleeps_on_the_wake_up_pipe_until_its_timeout_or_a_wake() -> None:
    """A loop with no lanes and no DDS reader to wait on (the plant; composed, every topic in
    process) sleeps on the wake-up pipe: to its timeout, or a wake() from another thread
    ends it at once, and a wake() before the sleep ends the next one (then none is left)."""
    w = LaneWait([_Path(None)], serving=0)
    try:
        t0 = time.monotonic()
        w.sleep(0.05)
        assert time.monotonic() - t0 >= 0.05 - 1e-3
        threading.Timer(0.02, w.wake).start()
        t0 = time.monotonic()
        w.sleep(5.0)
        assert time.monotonic() - t0 < 2.0
        w.wake()
        t0 = time.monotonic()
        w.sleep(5.0)
        assert time.monotonic() - t0 < 0.5  # the earlier wake-up
        t0 = time.monotonic()
        w.sleep(0.05)
        assert time.monotonic() - t0 >= 0.05 - 1e-3  # nothing left over
    finally:
        w.close()


def test_a_lanes_wait_ends_at_a_message_a_wake_or_its_timeout_a_mixed_one_polls_dds(
        lane, tmp_path: Path):
    path = _Path(lane)
    path.state = LANES
    w = LaneWait([path], serving=1)
    t0 = time.monotonic()
    assert w.wait(0.05) and time.monotonic() - t0 >= 0.05 - 1e-3  # the timeout
    writer = LaneWriter(TOPIC, tmp_path)
    writer.refresh()
    assert w.wait(5.0) and lane.read() == []  # its hello
    threading.Timer(0.02, writer.write, (b"x", time.time_ns())).start()
    t0 = time.monotonic()
    assert w.wait(5.0) and time.monotonic() - t0 < 2.0  # the message
    assert [d for d, _ in lane.read()] == [b"x"]
    threading.Timer(0.02, w.wake).start()
    t0 = time.monotonic()
    assert w.wait(5.0) and time.monotonic() - t0 < 2.0  # the wake-up, drained by the wait
    t0 = time.monotonic()
    assert w.wait(0.05) and time.monotonic() - t0 >= 0.05 - 1e-3  # no wake-up left over
    time.sleep(STATE_S)
    path.state = MIXED
    t0 = time.monotonic()
    assert w.wait(5.0) and time.monotonic() - t0 < DDS_POLL_S + 0.5
    writer.close()
    w.close()
    w.close()  # idempotent
    w.wake()  # after close: nothing to write to, no error


def test_a_wait_knows_how_long_after_its_timeout_nothing_of_its_process_ran(
        lane, process_pause):
    """``woke_late_s``: 0 for a wait that a message or its timeout ended in time; for one
    through whose timeout the whole process was stopped (a paused machine), the time from
    its timeout to the pause's end."""
    path = _Path(lane)
    path.state = LANES
    w = LaneWait([path], serving=1, timed=True)
    try:
        w.wake()
        assert w.wait(5.0) and w.woke_late_s == 0.0  # ended long before its timeout
        span = process_pause(0.005, 0.05)
        t0 = time.monotonic()
        assert w.wait(0.02)
        late = w.woke_late_s
        p0, p1 = span()
        assert p0 < t0 + 0.02 < p1 - 0.02  # stopped before the timeout, well past it
        assert p1 - t0 - 0.02 - 0.005 < late <= time.monotonic() - t0 - 0.02
    finally:
        w.close()


def test_a_wait_held_up_by_another_thread_of_its_process_is_not_late(lane, gil_holder):
    """A thread that got the GIL only after another thread's long C call ran late, but
    ``woke_late_s`` leaves out the CPU that thread used meanwhile (all of the delay, unless
    other processes took the CPU from it)."""
    path = _Path(lane)
    path.state = LANES
    w = LaneWait([path], serving=1, timed=True)
    try:
        span = gil_holder(0.005)
        t0 = time.monotonic()
        assert w.wait(0.02)
        back, late = time.monotonic(), w.woke_late_s
        while len(span) < 3:  # filled once the hold ended
            time.sleep(0.001)
        h0, _, cpu = span
        assert cpu > 0.03 and back >= h0 + cpu - 0.001  # it did wait for the holder
        # the holder's CPU is the process's: at most the rest of the delay is woke_late
        assert late <= max(back - t0 - 0.02 - cpu, 0.0) + 0.003, (late, back - t0, cpu)
    finally:
        w.close()


def test_the_pipe_is_closed(lane):
    path = _Path(lane)
    w = LaneWait([path], serving=1)
    fds = set(os.listdir("/proc/self/fd"))
    w.close()
    assert len(fds - set(os.listdir("/proc/self/fd"))) == 2
