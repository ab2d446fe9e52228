"""`bench/relay_floor.py`: a Python relay woken by a FIFO write, on two cores and on one, and
the relays that answer as a controller."""

from __future__ import annotations

import importlib.util
import os
import threading
from pathlib import Path

import pytest

from dcsms_ros.cdr import WRENCH_STAMPED, read_stamped
from dcsms_ros.protocols.lanes import FrameBuffer

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("relay_floor", ROOT / "bench" / "relay_floor.py")
assert _spec is not None and _spec.loader is not None
relay_floor = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(relay_floor)


@pytest.mark.parametrize("placement", ["spread", "one core"])
def test_every_frame_is_relayed_and_each_process_spends_cpu_per_message(placement: str) -> None:
    """0.4 s at 2 kHz, default scheduler: the relay passes on all 800 frames, and each of the
    three processes spends a positive CPU time per message, at most the period (500 us)."""
    cores = sorted(os.sched_getaffinity(0))
    other = cores[-2] if placement == "spread" and len(cores) > 1 else cores[-1]
    r = relay_floor.measure(0.4, 0, cores[-1], other)
    assert r["relayed"] == 800 and r["fifo"] is False
    for key in ("relay_us", "writer_us", "sink_us"):
        assert 0.0 < r[key] < 500.0


def _answers(work: str, tmp: Path, n: int) -> list[bytes]:
    """The answers ``work`` (``answer`` or ``inline``) writes for ``n`` frames of the writer."""
    a, b = tmp / f"{work}.a", tmp / f"{work}.b"
    os.mkfifo(a)
    os.mkfifo(b)
    out: list[bytes] = []

    def feed() -> None:
        with open(a, "wb", buffering=0) as f:
            f.writelines(relay_floor.frames(n))

    def drain() -> None:
        with open(b, "rb", buffering=0) as f:
            cut = FrameBuffer()
            while chunk := f.read(65536):
                out.extend(msg for msg, _t in cut.feed(chunk))

    threads = [threading.Thread(target=feed), threading.Thread(target=drain)]
    for t in threads:
        t.start()
    fn = relay_floor.answer if work == "answer" else relay_floor.inline
    cpu, got = fn(str(a), str(b), n, str(tmp / f"{work}.bag"))
    for t in threads:
        t.join(10.0)
        assert not t.is_alive()
    assert got == n and cpu > 0.0
    return out


def test_the_inline_relay_answers_every_frame_as_the_packages_parts_do(tmp_path: Path) -> None:
    """The two answering relays do the same work: 400 frames of a swept velocity, 400
    answers each, byte for byte the same wrenches (the loop's sections and gain, written out
    or called), none of them zero."""
    parts, inline = (_answers(w, tmp_path, 400) for w in ("answer", "inline"))
    assert len(parts) == 400 and parts == inline
    forces = [read_stamped(m, WRENCH_STAMPED, 1)[1][0] for m in parts]
    assert sum(f != 0.0 for f in forces) > 390
