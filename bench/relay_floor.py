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

``python bench/relay_floor.py [--seconds S] [--rt-priority P]`` prints one JSON line per
placement.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

PERIOD_S = 5e-4
FRAME = bytes(100)


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
    got, c0 = 0, None
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
        got += len(data) // len(FRAME)
        os.write(b, data)
    return (time.process_time() - (c0 or 0.0)) / max(got, 1), got


def sink(src: str, n: int) -> float:
    """Read ``n`` frames from FIFO ``src`` (blocking); CPU seconds per frame."""
    fd = os.open(src, os.O_RDONLY)
    got, c0 = 0, time.process_time()
    while got < n:
        data = os.read(fd, 65536)
        if not data:
            break
        got += len(data) // len(FRAME)
    return (time.process_time() - c0) / max(got, 1)


def writer(dst: str, n: int) -> float:
    """Write ``n`` frames into FIFO ``dst``, one at each deadline; CPU seconds per frame."""
    fd = os.open(dst, os.O_WRONLY)
    pc, c0 = time.perf_counter, time.process_time()
    t0 = pc() + 0.01
    for i in range(n):
        d = t0 + i * PERIOD_S - pc()
        if d > 0:
            time.sleep(d)
        os.write(fd, FRAME)
    return (time.process_time() - c0) / n


def _child(role: str, args: list[str], cpu: int, prio: int) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, __file__, "--role", role, "--cpu", str(cpu),
                             "--rt-priority", str(prio), *args], stdout=subprocess.PIPE,
                            text=True)


def measure(seconds: float, rt_priority: int, relay_cpu: int, other_cpu: int) -> dict[str, Any]:
    """One placement: the relay on ``relay_cpu``, the writer and the sink on ``other_cpu``.

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
                _child("relay", [a, b, str(n)], relay_cpu, rt_priority)]
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rt-priority", type=int, default=50)
    ap.add_argument("--role", choices=("writer", "relay", "sink"), help=argparse.SUPPRESS)
    ap.add_argument("--cpu", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("rest", nargs="*", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.role is None:
        for name, r in placements(a.seconds, a.rt_priority).items():
            print(json.dumps({"placement": name, **r}))
        return 0
    fifo = _realtime(a.cpu, a.rt_priority)
    frames = int(a.rest[-1])
    if a.role == "relay":
        cpu, frames = relay(a.rest[0], a.rest[1], frames)
    elif a.role == "sink":
        cpu = sink(a.rest[0], frames)
    else:
        cpu = writer(a.rest[0], frames)
    print(json.dumps({"cpu_s": cpu, "frames": frames, "fifo": fifo}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
