"""Per-topic recording statistics: message counts, sequence gaps and time gaps (no rclpy).

The recorder calls :meth:`TopicStats.add` from its subscription callbacks, so the method is
kept to a few integer operations per message.

Two kinds of gap are counted:

sequence gap
    The DDS ``publication_sequence_number`` of a publisher jumped by more than 1: messages were
    published but never reached the recorder (dropped by a full queue or a best-effort link).
    A *decrease* means the publisher restarted (new writer, numbering from 1 again) and is
    counted as a restart, not a gap.
time gap
    For stamped types, two consecutive header stamps further apart than
    :data:`GAP_FACTOR` times the topic's median stamp period: samples are missing from the
    *data* (the publisher skipped or stalled), whatever the transport did. The median is taken
    over the first :data:`WARMUP` intervals in which the stamp advanced (an unchanged stamp is
    never a gap; one that went back is counted at once), which are then re-checked; afterwards
    each interval is checked as it arrives, so memory stays constant on long recordings.

Both checks assume one publisher per topic; for a topic with several (``/diagnostics``,
where every node publishes at its own period) sequence numbers and stamps interleave, so both
are switched off (``checked = False``) and only the count is reported.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

#: An interval longer than this many median periods is a time gap.
GAP_FACTOR = 1.5
#: Intervals used to estimate the median stamp period.
WARMUP = 64
#: Gap examples kept per topic (all gaps are counted).
MAX_EXAMPLES = 5


@dataclass
class TopicStats:
    """Counters of one recorded topic.

    Attributes
    ----------
    topic, msgtype : str
    stamped : bool
        True if the type starts with a header stamp (time gaps are checked).
    checked : bool
        False when several publishers share the topic: no sequence or time-gap check.
    count : int
        Messages received (and written).
    seq_gaps, seq_missing, restarts : int
        Sequence jumps > 1, messages missing in them, sequence decreases.
    time_gaps, backwards : int
        Stamp intervals > GAP_FACTOR x median, and stamps that went backwards.
    median_period_ns : int or None
        Median header-stamp period (ns) once known.
    examples : list of (int, int)
        ``(stamp before, stamp after)`` in ns of the first time gaps.
    first_recv_ns, last_recv_ns : int
        Receive times (system clock, ns) of the first and last message.
    publishers : callable or None
        ``publishers()``: the topic's publisher count now, asked when the sequence numbers jump
        while the topic is checked: a publisher that appeared since the count was last set
        interleaves its own numbers (e.g. /diagnostics, written by every node), which is not a
        restart nor a gap; the checks stop as :meth:`set_publishers` would.
    """

    topic: str
    msgtype: str
    stamped: bool = False
    checked: bool = True
    count: int = 0
    seq_gaps: int = 0
    seq_missing: int = 0
    restarts: int = 0
    time_gaps: int = 0
    backwards: int = 0
    median_period_ns: int | None = None
    examples: list[tuple[int, int]] = field(default_factory=list)
    first_recv_ns: int = 0
    last_recv_ns: int = 0
    publishers: Callable[[], int] | None = None
    _last_seq: int | None = None
    _last_stamp: int | None = None
    _warm: list[tuple[int, int]] = field(default_factory=list)

    def add(self, seq: int | None, stamp_ns: int | None, recv_ns: int) -> None:
        """Account one message: its publication sequence number, header stamp (ns) and receive
        time (ns); ``seq`` or ``stamp_ns`` may be None when unknown."""
        self.count += 1
        if self.count == 1:
            self.first_recv_ns = recv_ns
        self.last_recv_ns = recv_ns
        if not self.checked:
            return
        if seq is not None:
            last = self._last_seq
            if last is not None:
                step = seq - last
                if step != 1 and self.publishers is not None and self.publishers() > 1:
                    self.checked = False  # another publisher's numbers, not a jump
                    return
                if step > 1:
                    self.seq_gaps += 1
                    self.seq_missing += step - 1
                elif step <= 0:
                    self.restarts += 1
            self._last_seq = seq
        if stamp_ns is not None:
            prev = self._last_stamp
            self._last_stamp = stamp_ns
            if prev is None:
                return
            if self.median_period_ns is None:
                # only advancing stamps estimate the period: kept, the intervals of stamps
                # that do not advance (a driver that leaves them zero) never settled it, and
                # the warm-up grew and was rescanned at every message (a zero-stamped 1 kHz
                # topic cost the recorder 0.74 ms per message after 40 s)
                if stamp_ns > prev:
                    self._warm.append((prev, stamp_ns))
                    if len(self._warm) >= WARMUP:
                        self._settle()
                elif stamp_ns < prev:
                    self.backwards += 1
            else:
                self._check(prev, stamp_ns)

    def lost_through(self, seq: int) -> None:
        """The publisher's messages up to number ``seq`` were published but some never came
        (a writer that dropped them, :mod:`.bagprocess`): those after the last one received
        count as a gap, as the next message would have shown."""
        if not self.checked:
            return
        last = self._last_seq or 0
        if seq > last:
            self.seq_gaps += 1
            self.seq_missing += seq - last
            self._last_seq = seq

    def set_publishers(self, n: int) -> None:
        """Update the publisher count: checks run only while it is at most 1; they restart
        from the next message when it drops back to 1 (e.g. a restarted node whose old
        writer left the graph), so the transition is not counted as a gap."""
        single = n <= 1
        if single and not self.checked:
            self._last_seq = self._last_stamp = None
        self.checked = single

    def _check(self, prev: int, cur: int) -> None:
        dt = cur - prev
        if dt < 0:
            self.backwards += 1
        elif self.median_period_ns and dt > GAP_FACTOR * self.median_period_ns:
            self.time_gaps += 1
            if len(self.examples) < MAX_EXAMPLES:
                self.examples.append((prev, cur))

    def _settle(self) -> None:
        """Fix the median period from the warm-up intervals (all advancing) and check them."""
        if not self._warm:
            return
        self.median_period_ns = int(statistics.median(b - a for a, b in self._warm))
        warm, self._warm = self._warm, []
        for a, b in warm:
            self._check(a, b)

    def finish(self) -> None:
        """Check the warm-up intervals of a topic that never had :data:`WARMUP` of them."""
        if self.median_period_ns is None and len(self._warm) >= 2:
            self._settle()

    @property
    def rate_hz(self) -> float:
        """Mean receive rate over the recording (Hz); 0 for fewer than two messages."""
        span = self.last_recv_ns - self.first_recv_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0

    @property
    def published(self) -> int | None:
        """Messages the topic's one publisher had published up to the last one received: its
        last publication sequence number (a DDS writer and the in-process bus both count from
        1). None when not known: no sequence numbers, several publishers, or a restart."""
        if not self.checked or self.restarts or self._last_seq is None:
            return None
        return self._last_seq

    @property
    def ok(self) -> bool:
        """No sequence gap, no time gap, no backwards stamp."""
        return not (self.seq_gaps or self.time_gaps or self.backwards)

    def state(self) -> dict[str, Any]:
        """Every counter, JSON-friendly, for :meth:`from_state` in another process (a bag
        writer process's, :mod:`.bagserve`); not the ``publishers`` callable."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "publishers"}
        out["examples"] = [list(e) for e in self.examples]
        out["_warm"] = [list(w) for w in self._warm]
        return out

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> TopicStats:
        """The counters :meth:`state` returned."""
        pairs = {k: [(int(a), int(b)) for a, b in state.get(k, [])] for k in ("examples", "_warm")}
        return cls(**{**state, **pairs})

    def as_dict(self) -> dict[str, object]:
        """The counters as a JSON-friendly dict."""
        return {"topic": self.topic, "type": self.msgtype, "count": self.count,
                "rate_hz": round(self.rate_hz, 3), "seq_gaps": self.seq_gaps,
                "seq_missing": self.seq_missing, "checked": self.checked,
                "published": self.published,
                "restarts": self.restarts, "time_gaps": self.time_gaps,
                "backwards": self.backwards, "median_period_ns": self.median_period_ns,
                "gap_examples_ns": [list(e) for e in self.examples]}


#: The bag's ``custom_data`` key under which a recorder leaves, as JSON ``{topic: count}``,
#: how many messages each topic's publisher had published (:attr:`TopicStats.published`).
PUBLISHED_KEY = "dcsms_ros.published"


def published_json(stats: Sequence[TopicStats]) -> str:
    """The :data:`PUBLISHED_KEY` value for ``stats`` (topics whose count is known)."""
    return json.dumps({s.topic: s.published for s in stats if s.published is not None},
                      sort_keys=True)


def read_published(custom_data: Mapping[str, str] | None) -> dict[str, int]:
    """The published counts a recorder left in a bag's ``custom_data`` (empty if none)."""
    try:
        raw = json.loads((custom_data or {}).get(PUBLISHED_KEY, "{}"))
    except (TypeError, ValueError):
        return {}
    return {str(k): int(v) for k, v in raw.items()} if isinstance(raw, dict) else {}


@dataclass
class Recording:
    """The outcome of one recording: the bag, its topics' counters and unseen topics."""

    path: str
    topics: list[TopicStats]
    missing: list[str] = field(default_factory=list)

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return {s.topic: s.count for s in self.topics}

    def text(self) -> str:
        """The human-readable report (:func:`format_report`)."""
        return f"bag: {self.path}\n" + format_report(self.topics, self.missing)

    def as_dict(self) -> dict[str, object]:
        """JSON-friendly summary: bag, total, per-topic counters, missing topics."""
        return {"bag": self.path, "total": sum(s.count for s in self.topics),
                "gaps": any(not s.ok for s in self.topics),
                "topics": [s.as_dict() for s in sorted(self.topics, key=lambda s: s.topic)],
                "missing": list(self.missing)}


def format_report(stats: Sequence[TopicStats], missing: Sequence[str] = ()) -> str:
    """A per-topic table (count, rate, gaps) and a verdict line, as text.

    Parameters
    ----------
    stats : sequence of TopicStats
    missing : sequence of str
        Requested topics never seen (no publisher appeared).
    """
    lines = [f"{'topic':<34} {'count':>9} {'rate Hz':>9} {'seq gaps':>9} {'time gaps':>9}"]
    for s in sorted(stats, key=lambda s: s.topic):
        seq = f"{s.seq_gaps}({s.seq_missing})" if s.checked else "n/a"
        tg = (str(s.time_gaps) if s.checked else "n/a") if s.stamped else "-"
        if s.backwards:
            tg += f" {s.backwards}<"
        lines.append(f"{s.topic:<34} {s.count:>9} {s.rate_hz:>9.1f} {seq:>9} {tg:>9}")
        for a, b in s.examples:
            lines.append(f"    time gap {(b - a) * 1e-6:.3f} ms after stamp {a * 1e-9:.6f} s "
                         f"(median period {(s.median_period_ns or 0) * 1e-6:.3f} ms)")
        if s.restarts:
            lines.append(f"    publisher restarted {s.restarts} time(s)")
    lines.extend(f"{t:<34} {'never published':>9}" for t in missing)
    total = sum(s.count for s in stats)
    bad = [s.topic for s in stats if not s.ok]
    lines.append(f"total {total} messages on {len(stats)} topics; "
                 + ("no gaps" if not bad else f"gaps on {', '.join(sorted(bad))}"))
    return "\n".join(lines)


__all__ = ["GAP_FACTOR", "MAX_EXAMPLES", "WARMUP", "Recording", "TopicStats", "format_report"]
