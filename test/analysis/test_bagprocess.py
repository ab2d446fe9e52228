"""A bag written by the bag writer process: the same bag and counters as in process, a
real-time writer that never waits for it, a lockstep one that loses nothing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.bagframes import TOPIC, pack_json, pack_messages
from dcsms_ros.analysis.bagprocess import ProcessBagWriter
from dcsms_ros.analysis.gaps import PUBLISHED_KEY, TopicStats
from dcsms_ros.cli.deploy import bag_published
from dcsms_ros.errors import BagError

VEL = "/dcsms/velocity/stage1"
MODE = "/dcsms/mode"


def _twists(n: int, skip: set[int] = frozenset()) -> list[tuple[bytes, int, int]]:
    """``(data, seq, t_ns)`` of n TwistStamped at 2 kHz, the samples in ``skip`` left out
    (a gap in the numbers and in the stamps)."""
    t = 10**18 + np.arange(n, dtype=np.int64) * 500_000
    data = cdr.encode_stamped(cdr.TWIST_STAMPED, t, "stage1", np.ones((n, 6)))
    return [(d, k + 1, int(t[k])) for k, d in enumerate(data) if k not in skip]


def _read(bag: Path) -> tuple[list[tuple[str, int, bytes]], dict[str, int]]:
    """The messages and the published counts of the closed bag."""
    with Reader(bag) as r:
        msgs = [(c.topic, t, bytes(d)) for c, t, d in r.messages()]
    return msgs, bag_published(bag)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_the_bag_and_its_counters_are_those_written(tmp_path: Path, storage: str) -> None:
    """Messages in batches (counted by the process) and one at a time (counted by the
    caller) come back in order, bit for bit; the process's counters equal
    :class:`TopicStats` fed directly, a gap of 3 samples included; its published count joins
    the caller's in the custom data."""
    msgs = _twists(2000, skip={1000, 1001, 1002})
    w = ProcessBagWriter(tmp_path / "bag", storage)
    vel = w.add_topic(VEL, cdr.TWIST_STAMPED, stats=True, stamped=True)
    w.add_topic(MODE, "std_msgs/msg/String")
    w.write(MODE, 5, cdr.encode_string("FBC"))
    for at in range(0, len(msgs), 64):
        w.write_frames([(vel, d, seq, t) for d, seq, t in msgs[at:at + 64]])
    w.set_custom_data(PUBLISHED_KEY, json.dumps({MODE: 1}))
    path = w.close()

    direct = TopicStats(VEL, cdr.TWIST_STAMPED, stamped=True)
    for d, seq, t in msgs:
        direct.add(seq, cdr.read_stamp(d), t)
    direct.finish()
    assert w.stats[VEL].state() == direct.state()
    assert direct.seq_missing == 3 and direct.time_gaps == 1
    got, custom = _read(path)
    assert got == [(MODE, 5, cdr.encode_string("FBC"))] + [(VEL, t, d) for d, _, t in msgs]
    assert custom == {MODE: 1, VEL: 2000}
    assert w.dropped == 0 and not (tmp_path / "bag.partial").exists()


def test_the_process_runs_on_the_cpus_asked_for_and_the_caller_keeps_its_own(
        tmp_path: Path) -> None:
    """``cpus``: every thread of the process on them, set at its start; the calling
    thread's CPUs are as before."""
    mine = os.sched_getaffinity(0)
    one = frozenset({min(mine)})
    w = ProcessBagWriter(tmp_path / "bag", cpus=one)
    w.wait_ready()
    tasks = os.listdir(f"/proc/{w._proc.pid}/task")
    assert {frozenset(os.sched_getaffinity(int(t))) for t in tasks} == {one}
    assert os.sched_getaffinity(0) == mine
    w.close()


def test_cpus_the_kernel_refuses_leave_the_process_on_the_callers(tmp_path: Path) -> None:
    """No CPU of ``cpus`` exists: the bag is written all the same, where the caller runs."""
    mine = os.sched_getaffinity(0)
    w = ProcessBagWriter(tmp_path / "bag", cpus=frozenset({4095}))
    w.wait_ready()
    assert os.sched_getaffinity(w._proc.pid) == mine == os.sched_getaffinity(0)
    assert w.close().exists()


def _stopped(w: ProcessBagWriter) -> int:
    pid = w._proc.pid
    os.kill(pid, signal.SIGSTOP)
    return pid


def test_a_real_time_writer_drops_and_counts_rather_than_wait(tmp_path: Path) -> None:
    """With the process stopped (SIGSTOP) a lossy writer goes on: what the pipe and the
    backlog do not hold is dropped and counted, and the process sees it as a gap. A writer
    that waited would never return here."""
    msgs = _twists(40_000)
    w = ProcessBagWriter(tmp_path / "bag", lossless=False, backlog_bytes=256 << 10)
    vel = w.add_topic(VEL, cdr.TWIST_STAMPED, stats=True, stamped=True)
    pid = _stopped(w)
    for at in range(0, len(msgs), 64):
        w.write_frames([(vel, d, seq, t) for d, seq, t in msgs[at:at + 64]])
    os.kill(pid, signal.SIGCONT)
    path = w.close()
    got, custom = _read(path)
    assert 0 < w.dropped < len(msgs)
    assert len(got) + w.dropped == len(msgs)
    st = w.stats[VEL]
    assert st.seq_missing == w.dropped and st.count == len(got)
    assert custom == {VEL: len(msgs)}  # the loss is visible in the bag


def test_a_lockstep_writer_waits_and_loses_nothing(tmp_path: Path) -> None:
    """A lossless writer waits once its backlog is full while the process is stopped, and
    goes on when it runs again: every message is in the bag."""
    msgs = _twists(40_000)
    w = ProcessBagWriter(tmp_path / "bag", lossless=True, backlog_bytes=256 << 10)
    vel = w.add_topic(VEL, cdr.TWIST_STAMPED, stats=True, stamped=True)
    pid = _stopped(w)
    done = threading.Event()

    def write() -> None:
        for at in range(0, len(msgs), 64):
            w.write_frames([(vel, d, seq, t) for d, seq, t in msgs[at:at + 64]])
        done.set()

    th = threading.Thread(target=write)
    th.start()
    # ~5 MB to write, the pipe (<= 1 MiB) and the backlog (256 KiB) full: it must wait
    assert not done.wait(2.0)
    os.kill(pid, signal.SIGCONT)
    th.join(60)
    assert done.is_set()
    path = w.close()
    got, _ = _read(path)
    assert w.dropped == 0 and len(got) == len(msgs) and w.stats[VEL].seq_gaps == 0


def test_an_existing_bag_is_refused_with_its_reason(tmp_path: Path) -> None:
    (tmp_path / "bag").mkdir()
    w = ProcessBagWriter(tmp_path / "bag")
    with pytest.raises(BagError, match="exists already"):
        w.add_topic(VEL, cdr.TWIST_STAMPED)
    assert w._proc.poll() == 2


def test_a_dead_process_is_an_error_that_counts_the_messages(tmp_path: Path) -> None:
    """Killed mid-run: the writer does not wait or fail per message; close says how many
    messages went nowhere."""
    msgs = _twists(20_000)
    w = ProcessBagWriter(tmp_path / "bag", lossless=True)
    vel = w.add_topic(VEL, cdr.TWIST_STAMPED, stats=True, stamped=True)
    w._proc.kill()
    w._proc.wait()
    for at in range(0, len(msgs), 64):
        w.write_frames([(vel, d, seq, t) for d, seq, t in msgs[at:at + 64]])
    with pytest.raises(BagError, match=r"exited -9; \d+ messages not written"):
        w.close()
    assert w.dropped > 0


def test_a_writer_that_died_leaves_a_closed_bag(tmp_path: Path) -> None:
    """The end of input without the last frame (the writing process died) closes the bag
    with every message that arrived, and exits 1."""
    msgs = _twists(500)
    proc = subprocess.Popen([sys.executable, "-m", "dcsms_ros.analysis.bagserve",
                             str(tmp_path / "bag")], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stdin is not None
    assert json.loads(proc.stdout.readline()) == {"ready": True}
    proc.stdin.write(pack_json(TOPIC, {"topic": VEL, "type": cdr.TWIST_STAMPED, "qos": "",
                                       "stats": False, "stamped": True}, 0))
    proc.stdin.write(pack_messages([(0, d, seq, t) for d, seq, t in msgs]))
    proc.stdin.close()
    assert proc.wait(60) == 1
    assert b"ended without closing" in proc.stderr.read()  # type: ignore[union-attr]
    got, _ = _read(tmp_path / "bag")
    assert Counter(t for t, _, _ in got) == {VEL: len(msgs)}
