"""The streaming batch path: simulate in blocks and write each block while the next is computed.

:class:`~dcsms_ros.core.engine.Simulation` returns the run block by block (times continue); a
writer thread encodes each block's topics as byte matrices (the fixed CDR layouts of
:mod:`dcsms_ros.cdr`) and hands them to the vectorized MCAP writer (:mod:`.mcapwrite`; SQLite 3
goes through :mod:`.bagio`), while the main thread simulates the next block (the compiled loop
releases the GIL). At most two blocks are alive at once, so memory stays bounded whatever the
duration. The bag holds the topics :func:`.export.export_result` writes, in the same order and
with the same bytes (``/dcsms/supervisor/state`` too: its topic is added at the first
transition, as the one-shot export has it only when there is one).

:func:`check_run` refuses, before anything is written, a run whose bag would not fit on the disk
(estimated from the message layouts and the compression measured on the graph's streams) or
whose duration is absurd.
"""

from __future__ import annotations

import queue
import shutil
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcsms_ros import cdr
from dcsms_ros.analysis.bagio import LATCHED_QOS, new_writer
from dcsms_ros.analysis.export import to_six
from dcsms_ros.analysis.mcaprecords import MESSAGE_HEADER, RowTemplate
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.analysis.reader import CONFIG_TOPIC, config_to_yaml
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.engine import SimResult, Simulation
from dcsms_ros.core.excitation import Excitation, ExcitationSpec
from dcsms_ros.core.model import actuator_count
from dcsms_ros.core.modes import ControllerId, Mode, controller_ids
from dcsms_ros.core.sensors import channel_layout
from dcsms_ros.core.supervisor import Transition
from dcsms_ros.errors import DcsmsError

#: Simulated seconds per block.
BLOCK_S = 10.0
#: Longest run accepted, s (about 116 days): longer is a typo, not a study.
MAX_DURATION_S = 1e7
#: Compressed / uncompressed size of a bag's streams (zstd level 1, measured on table1 and the
#: 6-DOF TEM: 0.45-0.55; taken high so the disk check errs on the safe side).
COMPRESSION_RATIO = 0.6
#: Free space kept on the disk beyond the estimate, bytes.
DISK_MARGIN = 64 << 20


@dataclass
class TopicLayout:
    """One per-sample topic and the layout of its messages."""

    topic: str
    layout: cdr.Layout


@dataclass
class StreamResult:
    """What a streamed run wrote and met."""

    samples: int
    counts: dict[str, int]
    counters: dict[str, int]
    modes: list[tuple[int, str]] = field(default_factory=list)
    trip: Any = None
    refused: list[tuple[int, str]] = field(default_factory=list)
    restarted: bool = False
    supervision: list[Transition] = field(default_factory=list)


def layouts(cfg: SystemConfig, channel_names: Sequence[str], actuator_names: Sequence[str],
            clock: bool = False, exc_stage: int | None = None) -> list[TopicLayout]:
    """The per-sample topics of a run, in the order a sample's messages are written
    (``exc_stage``: 0-based stage of an excitation, whose topic then follows the forces)."""
    def lay(topic: str, msgtype: str, *args: Any) -> TopicLayout:
        return TopicLayout(topic, cdr.message_layout(msgtype, *args))

    n = cfg.plant.num_stages
    out = [lay(topics.SENSORS_RAW, cdr.JOINT_STATE, "", channel_names,
               (0, len(channel_names), 0))]
    for b in topics.body_names(n):
        out.append(lay(topics.truth_topic(b), cdr.TWIST_STAMPED, b))
        out.append(lay(topics.velocity_topic(b), cdr.TWIST_STAMPED, b))
    out += [lay(topics.force_topic(c), cdr.WRENCH_STAMPED, ControllerId.parse(c).frame)
            for c in controller_ids(n)]
    if exc_stage is not None:
        out.append(lay(topics.EXCITATION, cdr.WRENCH_STAMPED, f"stage{exc_stage + 1}"))
    out.append(lay(topics.ACTUATORS_APPLIED, cdr.JOINT_STATE, "", actuator_names,
                   (0, 0, len(actuator_names))))
    if clock:
        out.append(lay(topics.CLOCK, cdr.CLOCK))
    return out


def _values(res: SimResult, clock: bool, exc_stage: int | None = None
            ) -> list[dict[str, NDArray[Any]]]:
    """Each topic's numeric fields for the rows of ``res`` (same order as :func:`layouts`)."""
    dof = res.cfg.plant.dof
    out: list[dict[str, NDArray[Any]]] = [{"velocity": res.raw}]
    for i in range(res.velocity.shape[1]):
        out.append({"twist": to_six(res.truth[:, i], dof)})
        out.append({"twist": to_six(res.velocity[:, i], dof)})
    out += [{"wrench": to_six(w, dof)} for w in res.wrench.values()]
    if exc_stage is not None:
        exc = (res.excitation[:, exc_stage] if res.excitation is not None
               else np.zeros((res.t.size, dof)))
        out.append({"wrench": to_six(exc, dof)})
    out.append({"effort": res.applied})
    if clock:
        out.append({})
    return out


def bytes_per_sample(cfg: SystemConfig) -> int:
    """Uncompressed MCAP bytes of one sample's messages."""
    n_ch, n_act = _channel_and_actuator_counts(cfg)
    return sum(MESSAGE_HEADER + t.layout.size for t in layouts(
        cfg, [f"c{i:02d}" for i in range(n_ch)], [f"stage1/a{i:02d}" for i in range(n_act)]))


def _channel_and_actuator_counts(cfg: SystemConfig) -> tuple[int, int]:
    return len(channel_layout(cfg)), sum(actuator_count(cfg, i)
                                         for i in range(1, cfg.plant.num_stages + 1))


def check_run(cfg: SystemConfig, duration_s: float, out: Path) -> int:
    """Refuse an absurd duration or a bag larger than the free disk space (one-line
    :class:`DcsmsError`), before anything is written; returns the estimated bytes."""
    if not 0 < duration_s <= MAX_DURATION_S:
        raise DcsmsError(f"--duration {duration_s:g}: must be > 0 and at most "
                         f"{MAX_DURATION_S:g} s")
    steps = int(round(duration_s * cfg.plant.rate_hz))
    est = int(steps * bytes_per_sample(cfg) * COMPRESSION_RATIO)
    parent = out.resolve().parent
    while not parent.exists():
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if est + DISK_MARGIN > free:
        raise DcsmsError(f"--duration {duration_s:g}: the bag would take about "
                         f"{est / 1e9:.3g} GB, {free / 1e9:.3g} GB free on {parent}")
    return est


_ABORT = object()


class _Writer:
    """The writer thread: owns the bag (SQLite objects must stay in one thread), encodes and
    writes the blocks handed over in :meth:`put`, closes or aborts the bag."""

    def __init__(self, cfg: SystemConfig, out: Path, storage: str, clock: bool,
                 exc_stage: int | None = None) -> None:
        self.cfg, self.clock, self.storage, self.out = cfg, clock, storage, out
        self.exc_stage = exc_stage
        self.bag: Any = None
        self.lay: list[TopicLayout] = []
        self._tpl: RowTemplate | None = None
        self._modes: list[tuple[int, str]] = []  # mode changes not written yet (a trip's
        # Passive may fall on the next block's first sample)
        self._states: list[Transition] = []  # supervisor transitions not written yet
        self.queue: queue.Queue[Any] = queue.Queue(maxsize=1)
        self.error: BaseException | None = None
        self.counts: dict[str, int] = {}
        self.busy_s = 0.0
        self.thread = threading.Thread(target=self._run, name="bag-writer", daemon=True)
        self.thread.start()

    def put(self, item: Any) -> None:
        """Hand over the next block (None: close the bag); raises the writer's error, if any."""
        while self.thread.is_alive():
            if self.error is not None:
                raise self.error
            try:
                self.queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue
        if self.error is not None:
            raise self.error

    def _run(self) -> None:
        try:
            self.bag = new_writer(self.out, self.storage)
            while (item := self.queue.get()) is not None:
                if item is _ABORT:
                    self.bag.abort()
                    return
                t = time.perf_counter()
                self._write(item)
                self.busy_s += time.perf_counter() - t
            self.bag.close()
            self.counts = dict(self.bag.counts)
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread
            self.error = exc
            if self.bag is not None:
                self.bag.abort()

    def _start(self, res: SimResult) -> None:
        self.lay = layouts(self.cfg, res.channel_names, res.actuator_names, self.clock,
                           self.exc_stage)
        self.bag.add_topic(CONFIG_TOPIC, cdr.STRING, LATCHED_QOS)
        self.bag.add_topic(topics.MODE, cdr.STRING, LATCHED_QOS)
        for lay in self.lay:
            self.bag.add_topic(lay.topic, lay.layout.msgtype)

    def _write(self, res: SimResult) -> None:
        dt_ns = int(round(self.cfg.plant.dt * 1e9))
        k0 = int(round(res.t[0] * self.cfg.plant.rate_hz)) if res.t.size else 0
        t_ns = (k0 + np.arange(res.t.size, dtype=np.int64)) * dt_ns
        if not self.lay:
            self._start(res)
            self.bag.write(CONFIG_TOPIC, int(t_ns[0]) if t_ns.size else 0,
                           cdr.encode_string(config_to_yaml(self.cfg)))
        names = [lay.topic for lay in self.lay]
        if isinstance(self.bag, McapBagWriter):  # encoded in place, in the bag's rows
            if self._tpl is None:
                self._tpl = self.bag.rows_template(names, [t.layout.template
                                                           for t in self.lay])
            tpl = self._tpl
            buf = tpl.encode(t_ns)
            for t, v, o in zip(self.lay, _values(res, self.clock, self.exc_stage),
                               tpl.offsets, strict=True):
                start = o + MESSAGE_HEADER
                cdr.encode_rows(t.layout, t_ns, v, buf[:, start:start + t.layout.size])
            rows = [buf]
        else:
            rows = [cdr.encode_rows(t.layout, t_ns, v) for t, v in zip(
                self.lay, _values(res, self.clock, self.exc_stage), strict=True)]
        # a mode message goes in at its sample, so the bag stays in time order
        end = k0 + t_ns.size
        self._modes += res.mode
        now = [(k - k0, lab) for k, lab in self._modes if k < end]
        self._modes = [(k, lab) for k, lab in self._modes if k >= end]
        self._states += res.supervision
        states = [tr for tr in self._states if tr.sample < end]
        self._states = [tr for tr in self._states if tr.sample >= end]
        if states and topics.SUPERVISOR_STATE not in self.bag.counts:
            self.bag.add_topic(topics.SUPERVISOR_STATE, cdr.STRING, LATCHED_QOS)
        cuts = sorted({k for k, _ in now} | {tr.sample - k0 for tr in states} | {0})
        labels = dict(now)
        for a, b in zip(cuts, [*cuts[1:], t_ns.size], strict=True):
            if a in labels:
                self.bag.write(topics.MODE, int(t_ns[a]), cdr.encode_string(labels[a]))
            for tr in states:
                if tr.sample - k0 == a:
                    self.bag.write(topics.SUPERVISOR_STATE, int(t_ns[a]),
                                   cdr.encode_string(tr.label))
            self._rows(t_ns[a:b], names, [r[a:b] for r in rows])

    def _rows(self, t: NDArray[np.int64], names: list[str], rows: list[NDArray[np.uint8]]) -> None:
        if isinstance(self.bag, McapBagWriter):
            assert self._tpl is not None
            self.bag.write_encoded(t, self._tpl, np.ascontiguousarray(rows[0]))
            return
        for i in range(t.size):  # SQLite: message by message, through rosbags
            for name, r in zip(names, rows, strict=True):
                self.bag.write(name, int(t[i]), r[i].tobytes())

    def finish(self) -> dict[str, int]:
        self.put(None)
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.counts

    def abort(self) -> None:
        if self.thread.is_alive():
            try:
                self.queue.put(_ABORT, timeout=30.0)
            except queue.Full:
                pass
            self.thread.join(30.0)


def stream_bag(cfg: SystemConfig, mode: Mode, duration_s: float, out: Path,
               seed: int | None = None, schedule: Sequence[tuple[float, Mode]] = (),
               ground: NDArray[np.float64] | None = None, storage: str = "mcap",
               clock: bool = False, block_s: float = BLOCK_S,
               progress: Callable[[float], None] | None = None,
               excite: Sequence[ExcitationSpec] = (), plant: SystemConfig | None = None,
               allow_unstable: bool = False) -> StreamResult:
    """Simulate ``duration_s`` and write the bag ``out`` block by block (see the module notes).

    ``excite`` (checked specifications, as ``dcsms sim --excite``) adds an actuator excitation,
    generated block by block; ``plant`` simulates a plant that differs from ``cfg`` (the
    controllers and the recorded configuration keep ``cfg``). A run whose fast path meets a
    non-finite value is written again from the start on the object path (which owns the fault
    handling), as :func:`~dcsms_ros.core.engine.simulate` does. ``supervisor`` (fresh, as
    :class:`~dcsms_ros.core.engine.Simulation` takes it) runs on the object path from the start,
    so it is never restarted; its transitions go into the bag and the result.
    """
    args = (cfg, mode, duration_s, out, seed, schedule, ground, storage, clock, block_s,
            progress)
    res = _stream(*args, None, excite, plant, allow_unstable)
    if res is None:
        res = _stream(*args, False, excite, plant, allow_unstable)
        assert res is not None
        res.restarted = True
    return res


def _stream(cfg: SystemConfig, mode: Mode, duration_s: float, out: Path, seed: int | None,
            schedule: Sequence[tuple[float, Mode]], ground: NDArray[np.float64] | None,
            storage: str, clock: bool, block_s: float,
            progress: Callable[[float], None] | None, fast: bool | None,
            excite: Sequence[ExcitationSpec] = (), plant: SystemConfig | None = None,
            allow_unstable: bool = False) -> StreamResult | None:
    steps = int(round(duration_s * cfg.plant.rate_hz))
    block = max(1, int(round(block_s * cfg.plant.rate_hz)))
    sim = Simulation(cfg, mode, seed, schedule, ground, trip=True, fast=fast, plant=plant,
                     allow_unstable=allow_unstable)
    exc = (Excitation(cfg, excite, cfg.disturbance.seed if seed is None else seed, duration_s)
           if excite else None)
    writer = _Writer(cfg, out, storage, clock, exc.stage - 1 if exc is not None else None)
    modes: list[tuple[int, str]] = []
    refused: list[tuple[int, str]] = []
    supervision: list[Transition] = []
    res: SimResult | None = None
    try:
        for k in range(0, steps, block):
            if exc is not None:
                sim.feed_excitation(exc.block(min(block, steps - k)))
            res = sim.run(min(block, steps - k))
            if res is None:
                writer.abort()
                return None
            modes += res.mode
            refused += res.refused
            supervision += res.supervision
            writer.put(res)
            if progress is not None:
                progress(min(k + block, steps) / steps)
        counts = writer.finish()
    except BaseException:
        writer.abort()
        raise
    counters = res.counters if res is not None else {}
    return StreamResult(steps, counts, counters, modes, sim.trip, refused,
                        supervision=supervision)


__all__ = ["BLOCK_S", "MAX_DURATION_S", "StreamResult", "TopicLayout", "bytes_per_sample",
           "check_run", "layouts", "stream_bag"]
