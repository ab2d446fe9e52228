"""Read a DCSMS bag into per-topic arrays, streaming in chunks with bounded memory.

Only what the analysis needs is kept: the decoupled velocities ``/dcsms/velocity/<body>``
(or ``/dcsms/truth/<body>`` when a bag has no decoupled ones), the applied actuator forces, the
excitation wrench (``/dcsms/force/excitation``), the mode timeline and the recorded
configuration. Values are kept as float32 (velocities of
~1e-6 m/s keep 7 significant digits, far below any estimator's variance) and twists only as
x, y, z, so an hour at 2 kHz needs ~0.6 GB (1-DOF, 2 stages) to ~0.8 GB (6-DOF, 8 coils)
by arithmetic (20 B per velocity sample, 8 B + 4 B per force channel); `make bench` measures a
real one-hour 1-DOF recording: 854 MB peak for the whole `analyze`, imports included.
Arrays are preallocated from the message counts in the metadata, so no concatenation doubles
the peak.

A bag that cannot be opened or is truncated raises :class:`BagError` naming the file: a
partial analysis of a cut-off run would silently drop the last modes, which is worse than a
clear error (``ros2 bag reindex`` repairs a bag whose metadata was lost).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from fnmatch import fnmatch
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapchunks
from dcsms_ros.analysis.series import (
    EXPORTABLE,
    TopicSeries,
    TopicSink,
)
from dcsms_ros.core import topics
from dcsms_ros.core.config import (
    SystemConfig,
    config_from_flat,
    params_text,
    parse_params_text,
)
from dcsms_ros.errors import BagError, ConfigError

#: std_msgs/String holding the flat parameters as YAML (published latched by the graph and
#: written by the batch engine) so an analysis can rebuild the analytic model.
CONFIG_TOPIC = topics.CONFIG
_BODY_TOPIC = re.compile(r"^/dcsms/(velocity|truth)/(ground|stage\d+)$")

Progress = Callable[[int, int], None]


@dataclass
class ModeEvent:
    """A mode switch: its bag time, the header-stamp time it maps to and its label."""

    log_ns: int
    stamp_ns: int
    label: str


@dataclass
class BagData:
    """Everything :func:`read_bag` extracts from one bag."""

    path: Path
    bodies: dict[str, TopicSeries] = field(default_factory=dict)  # body name -> velocity
    applied: TopicSeries | None = None
    excitation: TopicSeries | None = None  # frame_id: the excited stage
    modes: list[ModeEvent] = field(default_factory=list)
    #: ``/dcsms/supervisor/state`` as recorded: (bag time ns, text); the text carries the
    #: transition's plant time (:mod:`.timeline` parses it)
    states: list[tuple[int, str]] = field(default_factory=list)
    config_text: str | None = None
    source: str = "velocity"  # or "truth"
    warnings: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)  # all topics in the bag


def config_to_yaml(cfg: SystemConfig) -> str:
    """``cfg`` as the text of ``/dcsms/config``: a ROS 2 params file (see ``params_text``)."""
    return params_text(cfg.params or {})


def config_from_yaml(text: str, source: str = "/dcsms/config") -> SystemConfig:
    """Rebuild a :class:`SystemConfig` from ``/dcsms/config`` text: a params file, or a plain
    ``{dotted: value}`` mapping (bags written before the params-file form).

    Raises
    ------
    ConfigError
        If the text is not YAML of either form or a value is invalid; names ``source``.
    """
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: invalid YAML: {exc}") from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{source}: expected a ROS 2 params file or a mapping of dotted names")
    if doc and all(isinstance(v, dict) and "ros__parameters" in v for v in doc.values()):
        return config_from_flat(parse_params_text(text, source), source)
    return config_from_flat(doc, source)


def read_bag(path: str | Path, progress: Progress | None = None,
             chunk: int = 50_000) -> BagData:
    """Read the analysis topics of one bag.

    Parameters
    ----------
    path : str or Path
        rosbag2 directory (or a bare ``.mcap``/``.db3`` file).
    progress : callable(done, total), optional
        Called after every chunk with messages read so far and the total in the bag.
    chunk : int
        Messages per topic decoded at once (bounds the raw-buffer memory).

    Raises
    ------
    BagError
        If the bag is missing, unreadable, truncated or holds no velocity topics.
    """
    p = Path(path)
    return _with_reader(p, lambda reader: _read(reader, p, progress, chunk))


def _with_reader(p: Path, work: Callable[[Any], Any]) -> Any:
    """``work(reader)`` on an open rosbags Reader of ``p``; every failure but a BagError
    becomes one BagError naming the file."""
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    try:
        with Reader(p) as reader:
            return work(reader)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags/mcap/sqlite raise many types
        detail = " ".join(str(exc).split())  # one line: YAML errors span several
        raise BagError(f"{p}: cannot read bag (truncated or corrupted?): "
                       f"{type(exc).__name__}: {detail}") from None


def _read(reader: Any, path: Path, progress: Progress | None, chunk: int) -> BagData:
    data = BagData(path)
    conns = list(reader.connections)
    data.counts = {}
    for c in conns:
        data.counts[c.topic] = data.counts.get(c.topic, 0) + c.msgcount
    body_conns: dict[str, dict[str, Any]] = {"velocity": {}, "truth": {}}
    for c in conns:
        m = _BODY_TOPIC.match(c.topic)
        if m and c.msgtype == cdr.TWIST_STAMPED:
            body_conns[m.group(1)][m.group(2)] = c
    data.source = "velocity" if body_conns["velocity"] else "truth"
    chosen = body_conns[data.source]
    if not chosen:
        raise BagError(f"{path}: no /dcsms/velocity/* or /dcsms/truth/* TwistStamped topics "
                       f"(topics: {', '.join(sorted(data.counts)) or 'none'})")
    if data.source == "truth":
        data.warnings.append("no decoupled /dcsms/velocity/* topics: using /dcsms/truth/*")
    ref_body = "ground" if "ground" in chosen else min(chosen)
    wanted = {c.topic: c for c in chosen.values()}
    for c in conns:
        applied = c.topic == topics.ACTUATORS_APPLIED and c.msgtype == cdr.JOINT_STATE
        excite = c.topic == topics.EXCITATION and c.msgtype == cdr.WRENCH_STAMPED
        text = (c.topic in (topics.MODE, topics.SUPERVISOR_STATE, CONFIG_TOPIC)
                and c.msgtype == cdr.STRING)
        if applied or excite or text:
            wanted[c.topic] = c
    sinks = {t: TopicSink(c, keep_log=(t == chosen[ref_body].topic))
             for t, c in wanted.items() if c.msgtype != cdr.STRING}
    total = sum(c.msgcount for c in wanted.values())
    mode_log: list[tuple[int, str]] = []

    def on_text(conn: Any, t_ns: int, raw: bytes | np.ndarray) -> None:
        value = cdr.decode_string(bytes(raw))
        if conn.topic == topics.MODE:
            mode_log.append((t_ns, value.strip()))
        elif conn.topic == topics.SUPERVISOR_STATE:
            data.states.append((t_ns, value.strip()))
        elif data.config_text is None:
            data.config_text = value

    if not _read_chunks(reader, wanted, sinks, on_text, progress, total):
        mode_log.clear()
        data.states.clear()
        sinks = {t: TopicSink(s.conn, s.keep_log) for t, s in sinks.items()}
        _read_messages(reader, wanted, sinks, on_text, progress, total, chunk)
    if progress is not None:
        progress(total, total)
    for body, c in chosen.items():
        data.bodies[body] = sinks[c.topic].result()
    if topics.ACTUATORS_APPLIED in sinks:
        data.applied = sinks[topics.ACTUATORS_APPLIED].result()
    if topics.EXCITATION in sinks:
        data.excitation = sinks[topics.EXCITATION].result()
    data.modes = place_modes(mode_log, data.bodies[ref_body])
    for s in sinks.values():
        if s.fallback:
            data.warnings.append(f"{s.conn.topic}: {s.fallback} chunk(s) decoded by the slow "
                                 "path (layout changed between messages)")
    return data


def _mcap_files(reader: Any) -> list[Path] | None:
    """The storage files when every one is MCAP (rosbags reader internals, checked)."""
    storages = getattr(reader.storage, "storages", [reader.storage])
    paths = [getattr(s, "path", None) for s in storages]
    if not paths or not all(isinstance(p, Path) and p.suffix == ".mcap" for p in paths):
        return None
    return [p for p in paths if isinstance(p, Path)]


def _read_chunks(reader: Any, wanted: dict[str, Any], sinks: dict[str, TopicSink],
                 text: Callable[[Any, int, Any], None], progress: Progress | None,
                 total: int) -> bool:
    """Fast path: whole MCAP chunks as byte matrices (:mod:`.mcapchunks`). False when the
    files need the rosbags reader (not MCAP, unindexed, unknown compression, or a topic whose
    messages are out of log-time order across chunks); nothing is kept from a False run."""
    files = _mcap_files(reader)
    if files is None:
        return False
    done = 0

    def tick(n: int) -> None:
        nonlocal done
        done += n
        if progress is not None:
            progress(done, total)

    try:
        for f in files:
            chans, chunks = mcapchunks.summary(f)
            ids = {cid: wanted[t] for cid, (t, schema) in chans.items()
                   if t in wanted and schema == wanted[t].msgtype}
            for block in mcapchunks.iter_blocks(f, set(ids), chunks, tick):
                conn = ids[block.channel]
                if conn.msgtype != cdr.STRING:
                    if not sinks[conn.topic].add_block(block):
                        return False
                    continue
                payloads: Any = block.rows if block.rows is not None else block.buffers
                for t_ns, raw in zip(block.log_ns.tolist(), payloads, strict=True):
                    text(conn, t_ns, raw)
    except mcapchunks.Unsupported:
        return False
    return True


def _read_messages(reader: Any, wanted: dict[str, Any], sinks: dict[str, TopicSink],
                   text: Callable[[Any, int, Any], None], progress: Progress | None,
                   total: int, chunk: int) -> None:
    """rosbags path: message by message (SQLite 3 bags, unindexed MCAP)."""
    done = 0
    for conn, t_ns, raw in reader.messages(connections=list(wanted.values())):
        if conn.msgtype == cdr.STRING:
            text(conn, t_ns, raw)
            continue
        sink = sinks[conn.topic]
        sink.add(t_ns, raw)
        if len(sink.raw) >= chunk:
            sink.flush()
            done += chunk
            if progress is not None:
                progress(done, total)
    for sink in sinks.values():
        sink.flush()


def read_topics(path: str | Path, names: Iterable[str] | None = None,
                progress: Progress | None = None,
                strict: bool = True) -> tuple[dict[str, TopicSeries], list[tuple[int, str]]]:
    """Every component of the chosen topics at full precision (float64), and the mode log.

    Parameters
    ----------
    path : str or Path
        rosbag2 directory (or a bare ``.mcap``/``.db3`` file).
    names : iterable of str, optional
        Topics or ``fnmatch`` patterns (``/dcsms/velocity/*``); default: every TwistStamped,
        WrenchStamped and JointState topic under ``/dcsms``.
    progress : callable(done, total), optional
    strict : bool
        Every name must match a topic with numbers (else BagError); False skips those that
        match none.

    Returns
    -------
    series : dict of topic to TopicSeries
        Values (K, n) float64 in SI units; columns ``vx vy vz wx wy wz`` (m/s, rad/s),
        ``fx fy fz mx my mz`` (N, N*m), or ``<field>:<joint>`` (JointState).
    modes : list of (bag time ns, label)
        ``/dcsms/mode`` as recorded.

    Raises
    ------
    BagError
        Unreadable bag, a named topic that is missing, or one of a type without numbers.
    """
    p = Path(path)
    pats = list(names) if names is not None else ["/dcsms/*"]
    modes: list[tuple[int, str]] = []

    def on_text(conn: Any, t_ns: int, raw: bytes | np.ndarray) -> None:
        modes.append((t_ns, cdr.decode_string(bytes(raw)).strip()))

    def work(reader: Any) -> dict[str, TopicSeries]:
        conns = list(reader.connections)
        wanted: dict[str, Any] = {}
        for pat in pats:
            hit = [c for c in conns if fnmatch(c.topic, pat)]
            num = [c for c in hit if c.msgtype in EXPORTABLE]
            if names is not None and strict and not num:
                why = (f"type {hit[0].msgtype} has no numeric samples to export" if hit
                       else "no such topic")
                raise BagError(f"{p}: {pat}: {why} (topics: "
                               f"{', '.join(sorted({c.topic for c in conns}))})")
            wanted.update({c.topic: c for c in num})
        wanted.update({c.topic: c for c in conns
                       if c.topic == topics.MODE and c.msgtype == cdr.STRING})
        sinks = {t: TopicSink(c, keep_log=True, full=True) for t, c in wanted.items()
                 if c.msgtype != cdr.STRING}
        total = sum(c.msgcount for c in wanted.values())
        if not _read_chunks(reader, wanted, sinks, on_text, progress, total):
            modes.clear()
            sinks = {t: TopicSink(s.conn, True, full=True) for t, s in sinks.items()}
            _read_messages(reader, wanted, sinks, on_text, progress, total, 50_000)
        return {t: s.result() for t, s in sorted(sinks.items())}

    series = _with_reader(p, work)
    return series, sorted(modes)


def place_modes(mode_log: Iterable[tuple[int, str]], ref: TopicSeries) -> list[ModeEvent]:
    """Map each switch's bag time to the header stamp of the first reference sample after it.

    String has no header, so a switch only has its bag (receive) time; when the recorder runs
    on wall time and the graph on sim time the two clocks differ, but the reference topic has
    both, which places the switch on the data's own time axis.
    """
    out: list[ModeEvent] = []
    log = ref.log_ns
    if log is None or log.size == 0:
        return out
    # rows are in stamp order; a publisher that reordered its stamps leaves the bag times
    # unsorted, and the first sample recorded after a switch is the first in bag time
    order = np.argsort(log, kind="stable") if np.any(np.diff(log) < 0) else None
    by_log = log if order is None else log[order]
    for t_ns, label in sorted(mode_log):
        i = int(np.searchsorted(by_log, t_ns, side="left"))
        if i >= by_log.size:
            continue  # switched after the last sample: no data in that mode
        if out and out[-1].label == label:
            continue  # a re-published (latched) label is not a switch
        row = i if order is None else int(order[i])
        out.append(ModeEvent(int(t_ns), int(ref.stamp_ns[row]), label))
    return out


__all__ = ["CONFIG_TOPIC", "BagData", "ModeEvent", "config_from_yaml", "config_to_yaml",
           "place_modes", "read_bag", "read_topics"]
