"""The machine's floor for one process per node: the CPU a Python process spends per message
when all it does is relay it, woken by the write, as a node on host lanes is.

A writer (the plant's role) sleeps to each deadline of a 500 us period and writes a 100-byte
frame into FIFO A; the relay (a controller's role) blocks in ``select`` on A, reads what came
and writes it into FIFO B; a sink (the plant's force lane) reads B. All three run under
SCHED_FIFO, as the graph's hot threads do. Two placements:

* ``spread``: the relay on one core, the writer and the sink on the other, so each wake-up
  crosses cores, as most of the graph's do (the kernel pushes a woken real-time thread to the
  core that runs nothing of its class);
* ``one core``: all three on one core: a wake-up only queues the woken thread there.

The difference is what waking a thread on another core costs on this machine (an
inter-processor interrupt; in a virtual machine, exits to the hypervisor on both sides).

``--answer`` runs, in the spread placement, a relay that does a feedback controller's
work as well, with the package's own parts called flat from the loop (:func:`answer`): frames
cut by :class:`~dcsms_ros.protocols.lanes.FrameBuffer`, the twist decoded, the guard's test,
:class:`~dcsms_ros.protocols.responder.Answerer`, the table's ``fb_stage2`` loop, the wrench
encoded, framed and written, and each answer recorded in an MCAP bag in batches.
``inline`` does the same work written out in the loop (:func:`inline`: ``struct`` and
float arithmetic on the same sections, no call into the package per frame), the least a
Python controller can spend. Their CPU above the relay's is what the work costs, called
through the parts or written out; a controller node's CPU above the answering relay's is its
framework's layers (hot loop, lane input, publisher, part recorder).

``python bench/relay_floor.py [--seconds S] [--rt-priority P]`` prints one JSON line per
placement; ``--answer [--rounds N]`` one line with the three relays' CPU per message.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cdr import TWIST_STAMPED, WRENCH_STAMPED, StampedWriter, read_stamped
from dcsms_ros.cdr.layout import STAMP_AT, VECTOR_FIELD, message_layout
from dcsms_ros.core.config import load_config
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.protocols.lanes import HEADER, FrameBuffer, frame
from dcsms_ros.protocols.responder import Answerer
from dcsms_ros.ros.guard import MAX_VELOCITY_MPS

PERIOD_S = 5e-4
#: A ``velocity/stage2`` frame of table1 (the writer's frames differ in their stamps only).
FRAME_ID = "stage2"
#: Answers recorded per batch (as a node's part recorder).
BATCH = 64


def frames(n: int) -> list[bytes]:
    """``n`` lane frames of TwistStamped stamped 0, 500 us, ..., a small vertical velocity."""
    w = StampedWriter(TWIST_STAMPED, FRAME_ID, 1)
    ns = [int(round(i * PERIOD_S * 1e9)) for i in range(n)]
    return [frame(w.encode(t, np.array([1e-6 * math.sin(t * 1e-7)])), t) for t in ns]


def _realtime(cpu: int, prio: int) -> bool:
    """Pin this process to ``cpu`` and put it under SCHED_FIFO ``prio`` (False if refused)."""
    os.sched_setaffinity(0, {cpu})
    if not prio:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
    except OSError:
        return False
    return True


def relay(src: str, dst: str, n: int) -> tuple[float, int]:
    """Relay ``n`` frames from FIFO ``src`` to FIFO ``dst``; CPU seconds per frame from the
    first on, and the frames relayed."""
    a = os.open(src, os.O_RDONLY | os.O_NONBLOCK)
    b = os.open(dst, os.O_WRONLY)
    got, c0, size = 0, None, len(frames(1)[0])
    while got < n:
        select.select([a], (), (), 1.0)
        try:
            data = os.read(a, 65536)
        except BlockingIOError:
            continue
        if not data:
            break
        if c0 is None:
            c0 = time.process_time()
        got += len(data) // size
        os.write(b, data)
    return (time.process_time() - (c0 or 0.0)) / max(got, 1), got


class _Answering:
    """The ends of an answering relay: its FIFOs and the bag its answers are recorded in, in
    batches as a node's part recorder does."""

    def __init__(self, src: str, dst: str, bag: str) -> None:
        self.src = os.open(src, os.O_RDONLY | os.O_NONBLOCK)
        self.dst = os.open(dst, os.O_WRONLY)
        self.writer = McapBagWriter(bag, defer_flush=True)
        self.writer.add_topic("/force", "geometry_msgs/msg/WrenchStamped", "")
        self.batch: list[tuple[str, int, bytes]] = []
        self.c0: float | None = None

    def chunks(self) -> Iterator[bytes]:
        """What the source FIFO holds, one read at each wake-up, until its writer closes it
        (the CPU clock starts at the first)."""
        while True:
            select.select([self.src], (), (), 1.0)
            try:
                data = os.read(self.src, 65536)
            except BlockingIOError:
                continue
            if not data:
                return
            if self.c0 is None:
                self.c0 = time.process_time()
            yield data

    def close(self, got: int) -> tuple[float, int]:
        """CPU seconds per frame since the first, and ``got``; the bag written, the ends
        closed."""
        cpu = (time.process_time() - (self.c0 or 0.0)) / max(got, 1)
        self.writer.write_all(self.batch)
        self.writer.close()
        os.close(self.src)
        os.close(self.dst)
        return cpu, got


def answer(src: str, dst: str, n: int, bag: str) -> tuple[float, int]:
    """As :func:`relay`, each frame answered as a feedback controller does (see the module
    notes), the answers recorded in ``bag``; CPU seconds per frame, and the frames answered."""
    loop = make_controller(load_config(), "fb_stage2", enabled=True)
    enc = StampedWriter(WRENCH_STAMPED, "stage2", 1)
    cut = FrameBuffer()
    ends = _Answering(src, dst, bag)
    batch, writer = ends.batch, ends.writer

    def publish(data: bytes) -> None:
        t_ns = time.time_ns()
        os.write(ends.dst, frame(data, t_ns))
        batch.append(("/force", t_ns, data))
        if len(batch) >= BATCH:
            writer.write_all(batch)
            batch.clear()

    answers: Answerer[bytes] = Answerer(publish, False, lambda: True)
    got = 0
    for data in ends.chunks():
        for msg, _t in cut.feed(data):
            ns, x = read_stamped(msg, TWIST_STAMPED, 1)
            if not all(abs(v) <= MAX_VELOCITY_MPS for v in x.tolist()):
                x = np.full(1, np.nan)
            if answers.due(ns):
                w = loop.step(x)
                if not all(map(math.isfinite, w.tolist())):
                    w = np.zeros(1)
                answers.reply(ns, enc.encode(ns, w))
            got += 1
        if got >= n:
            break
    return ends.close(got)


def inline(src: str, dst: str, n: int, bag: str) -> tuple[float, int]:
    """:func:`answer`'s work written out in its loop: the frame header, the stamp and the
    vertical velocity unpacked with ``struct``, the guard, the stamp order, the fade and the
    loop's own sections (transposed direct form II on floats), the wrench packed into the
    message's template, framed, written and recorded in batches. CPU seconds per frame, and
    the frames answered."""
    cfg = load_config()
    loop = make_controller(cfg, "fb_stage2", enabled=True)
    sections = [list(map(float, row)) for row in loop.filter.coefficients()[0]]
    # enabled: at full gain from the first sample, as the loop's fader (the same division)
    fade_n = max(1, round(cfg.control.fade_time_s / cfg.plant.dt))
    fade_k = fade_n
    states = [[0.0, 0.0] for _ in sections]
    vin = message_layout(TWIST_STAMPED, FRAME_ID).fields[VECTOR_FIELD[TWIST_STAMPED]][0] + 16
    out = message_layout(WRENCH_STAMPED, "stage2")
    vout = out.fields[VECTOR_FIELD[WRENCH_STAMPED]][0] + 16
    stamp, f8 = struct.Struct("<iI"), struct.Struct("<d")
    template = bytes(out.buf)
    ends = _Answering(src, dst, bag)
    batch, writer, dst_fd = ends.batch, ends.writer, ends.dst
    unpack_header, unpack_stamp, unpack_f8 = HEADER.unpack_from, stamp.unpack_from, f8.unpack_from
    hs, last, got = HEADER.size, -1, 0
    for data in ends.chunks():
        i, m = 0, len(data)
        while i + hs <= m:
            ln, _t = unpack_header(data, i)
            body, i = i + hs, i + hs + ln
            sec, nsec = unpack_stamp(data, body + STAMP_AT)
            ns = sec * 1_000_000_000 + nsec
            got += 1
            if ns <= last:
                continue
            last = ns
            (u,) = unpack_f8(data, body + vin)
            if fade_k < fade_n:
                fade_k += 1
            w = 0.0  # implausible: zero force, the sections untouched (as the loop's NaN)
            if abs(u) <= MAX_VELOCITY_MPS:
                for (b0, b1, b2, _a0, a1, a2), z in zip(sections, states, strict=True):
                    y = b0 * u + z[0]
                    z[0] = b1 * u - a1 * y + z[1]
                    z[1] = b2 * u - a2 * y
                    u = y
                w = -(fade_k / fade_n) * u
                if not math.isfinite(w):
                    w = 0.0
            msg = bytearray(template)
            stamp.pack_into(msg, STAMP_AT, sec, nsec)
            f8.pack_into(msg, vout, w)
            data_out = bytes(msg)
            t_ns = time.time_ns()
            os.write(dst_fd, HEADER.pack(len(data_out), t_ns) + data_out)
            batch.append(("/force", t_ns, data_out))
            if len(batch) >= BATCH:
                writer.write_all(batch)
                batch.clear()
        if got >= n:
            break
    return ends.close(got)


def sink(src: str, n: int) -> float:
    """Read FIFO ``src`` (blocking) until its writer closes it; CPU seconds per frame of the
    ``n`` sent."""
    fd = os.open(src, os.O_RDONLY)
    c0 = time.process_time()
    while os.read(fd, 65536):
        pass
    return (time.process_time() - c0) / max(n, 1)


def writer(dst: str, n: int) -> float:
    """Write ``n`` frames into FIFO ``dst``, one at each deadline; CPU seconds per frame."""
    fd = os.open(dst, os.O_WRONLY)
    todo = frames(n)
    pc, c0 = time.perf_counter, time.process_time()
    t0 = pc() + 0.01
    for i in range(n):
        d = t0 + i * PERIOD_S - pc()
        if d > 0:
            time.sleep(d)
        os.write(fd, todo[i])
    return (time.process_time() - c0) / n


def _child(role: str, args: list[str], cpu: int, prio: int) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, __file__, "--role", role, "--cpu", str(cpu),
                             "--rt-priority", str(prio), *args], stdout=subprocess.PIPE,
                            text=True)


def measure(seconds: float, rt_priority: int, relay_cpu: int, other_cpu: int,
            work: str = "relay") -> dict[str, Any]:
    """One placement: the relay on ``relay_cpu``, the writer and the sink on ``other_cpu``;
    ``work``: ``relay`` (pass each frame on), ``answer`` (:func:`answer`) or ``inline``
    (:func:`inline`).

    Returns
    -------
    dict
        ``relay_us``, ``writer_us``, ``sink_us``: CPU per message (us) of each process;
        ``relayed``: the messages the relay passed on (of ``seconds`` / 500 us); ``fifo``:
        whether SCHED_FIFO was granted.
    """
    n = int(round(seconds / PERIOD_S))
    with tempfile.TemporaryDirectory(prefix="relay-floor-") as d:
        a, b = str(Path(d) / "a"), str(Path(d) / "b")
        os.mkfifo(a)
        os.mkfifo(b)
        kids = [_child("sink", [b, str(n)], other_cpu, rt_priority),
                _child(work, [a, b, *([str(Path(d) / "bag")] if work != "relay" else []),
                              str(n)], relay_cpu, rt_priority)]
        w = _child("writer", [a, str(n)], other_cpu, rt_priority)
        outs = [json.loads(k.communicate(timeout=seconds * 4 + 30)[0]) for k in [w, *kids]]
    return {"relay_us": outs[2]["cpu_s"] * 1e6, "writer_us": outs[0]["cpu_s"] * 1e6,
            "sink_us": outs[1]["cpu_s"] * 1e6, "relayed": outs[2]["frames"],
            "fifo": all(o["fifo"] for o in outs)}


def placements(seconds: float, rt_priority: int) -> dict[str, dict[str, Any]]:
    """:func:`measure` spread over two cores and on one core (the last two cores the process
    may use; one core only: both are the same placement)."""
    cores = sorted(os.sched_getaffinity(0))
    last, other = cores[-1], cores[-2] if len(cores) > 1 else cores[-1]
    return {"spread": measure(seconds, rt_priority, last, other),
            "one core": measure(seconds, rt_priority, last, last)}


#: The relays :func:`answer_rounds` compares.
WORKS = ("relay", "inline", "answer")


def answer_rounds(seconds: float, rt_priority: int, rounds: int) -> dict[str, list[float]]:
    """:func:`measure` spread for each of :data:`WORKS` in turn, ``rounds`` times (this
    host's speed drifts within minutes: compare within a round). Returns the CPU per message
    (us) of each, ``<work>_us``."""
    cores = sorted(os.sched_getaffinity(0))
    last, other = cores[-1], cores[-2] if len(cores) > 1 else cores[-1]
    out: dict[str, list[float]] = {f"{w}_us": [] for w in WORKS}
    for _ in range(rounds):
        for w in WORKS:
            out[f"{w}_us"].append(measure(seconds, rt_priority, last, other, w)["relay_us"])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rt-priority", type=int, default=50)
    ap.add_argument("--answer", action="store_true",
                    help="the plain relay and the two answering ones in turn (--rounds), "
                         "spread over two cores")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--role", choices=("writer", *WORKS, "sink"),
                    help=argparse.SUPPRESS)
    ap.add_argument("--cpu", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("rest", nargs="*", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.role is None and a.answer:
        print(json.dumps(answer_rounds(a.seconds, a.rt_priority, a.rounds)))
        return 0
    if a.role is None:
        for name, r in placements(a.seconds, a.rt_priority).items():
            print(json.dumps({"placement": name, **r}))
        return 0
    fifo = _realtime(a.cpu, a.rt_priority)
    count = int(a.rest[-1])
    if a.role == "relay":
        cpu, count = relay(a.rest[0], a.rest[1], count)
    elif a.role in ("answer", "inline"):
        cpu, count = (answer if a.role == "answer" else inline)(a.rest[0], a.rest[1], count,
                                                               a.rest[2])
    elif a.role == "sink":
        cpu = sink(a.rest[0], count)
    else:
        cpu = writer(a.rest[0], count)
    print(json.dumps({"cpu_s": cpu, "frames": count, "fifo": fifo}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
