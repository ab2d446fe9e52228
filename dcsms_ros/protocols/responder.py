"""The per-sample answer protocol of the decoupling, the controllers and the excitation.

Each of them answers every input sample with one output stamped like it. In lockstep the plant
republishes a sample whose answers are missing; a node that already answered it must not step
its filters again, so a repeated stamp gets the cached answer (published again). A stamp older
than the newest answered one is dropped (out of order). Only a new stamp is computed, and the
first one only once the first-sample gate (:mod:`.gate`) is open. :class:`Answerer` is the
whole protocol; :class:`StampResponder` its stamp bookkeeping.
"""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from typing import Generic, TypeVar

from dcsms_ros.protocols.gate import MATCH_TIMEOUT_S, FirstSampleGate

T = TypeVar("T")


class Verdict(enum.Enum):
    """What to do with an input."""

    NEW = 0  #: compute and answer (then :meth:`StampResponder.store`)
    REPEAT = 1  #: publish :attr:`StampResponder.cache` again
    OLD = 2  #: drop


class StampResponder(Generic[T]):
    """The newest answered stamp and its answer.

    Attributes
    ----------
    last_ns : int
        Stamp of the newest answered input, ns (-1 before the first).
    cache : T or None
        Its answer.
    repeats, out_of_order : int
        Inputs answered from the cache, and dropped.
    """

    def __init__(self) -> None:
        self.last_ns = -1
        self.cache: T | None = None
        self.repeats = 0
        self.out_of_order = 0

    def judge(self, stamp_ns: int) -> Verdict:
        """Verdict on an input stamped ``stamp_ns`` (counts repeats and drops)."""
        if stamp_ns == self.last_ns and self.cache is not None:
            self.repeats += 1
            return Verdict.REPEAT
        if stamp_ns < self.last_ns:
            self.out_of_order += 1
            return Verdict.OLD
        return Verdict.NEW

    def advance(self, stamp_ns: int) -> None:
        """The input stamped ``stamp_ns`` is computed, its answer not known yet (real time:
        only the newest of a burst is answered, :meth:`store`-d then)."""
        self.last_ns = stamp_ns
        self.cache = None

    def store(self, stamp_ns: int, answer: T) -> T:
        """Remember ``answer`` to the input stamped ``stamp_ns``; returns it."""
        self.last_ns = stamp_ns
        self.cache = answer
        return answer


class Answerer(StampResponder[T]):
    """Answer each new input once, repeat the answer to a retransmission, drop older ones.

    Per input: ``if answerer.due(stamp_ns): answerer.reply(stamp_ns, compute(...))``.

    Parameters
    ----------
    publish : callable
        Sends an answer (a repeat too).
    gated : bool
        Hold the first answer until ``matched()`` (lockstep); False: answer from the start.
    matched : callable
        True once every reader of the answers is matched (polled only while gated).
    timeout_s : float
        Longest hold of the first answer, s.
    on_timeout : callable, optional
        Called once if the gate opened by the timeout (the node logs it).
    clock : callable
        Monotonic time, s (a fake in tests).
    """

    def __init__(self, publish: Callable[[T], None], gated: bool, matched: Callable[[], bool],
                 timeout_s: float = MATCH_TIMEOUT_S, on_timeout: Callable[[], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.publish = publish
        self.gate = FirstSampleGate(gated, timeout_s)
        self._matched = matched
        self._on_timeout = on_timeout
        self._clock = clock

    def due(self, stamp_ns: int) -> bool:
        """True if the input stamped ``stamp_ns`` is to be computed and :meth:`reply`-ed; a
        repeat is published from the cache here, an old or held (gated) one is dropped."""
        if stamp_ns > self.last_ns and self.gate.open:
            return True  # the usual sample (NEW, gate open), decided without judge's call
        verdict = self.judge(stamp_ns)
        if verdict is Verdict.NEW:
            return self.gate.open or self._first()
        if verdict is Verdict.REPEAT:
            self.publish(self.cache)  # type: ignore[arg-type]  # judge: cache is set
        return False

    def reply(self, stamp_ns: int, answer: T) -> None:
        """Store and publish ``answer`` to the input stamped ``stamp_ns``."""
        self.last_ns, self.cache = stamp_ns, answer  # store(), a call less a sample
        self.publish(answer)

    def _first(self) -> bool:
        ok = self.gate.ready(self._matched, self._clock())
        if ok and self.gate.timed_out and self._on_timeout is not None:
            self._on_timeout()
        return ok


def skipped(last_ns: int, ns: int, rate_hz: float, cap: int) -> int:
    """Whole samples between an answered stamp ``last_ns`` and the next one ``ns`` (ns) at
    ``rate_hz``, at most ``cap``; 0 before the first answer (``last_ns`` < 0)."""
    if last_ns < 0:
        return 0
    return max(min(round((ns - last_ns) * rate_hz / 1e9) - 1, cap), 0)


def skip_free_ns(rate_hz: float) -> float:
    """A gap (ns) between answered stamps at ``rate_hz`` below which :func:`skipped` is 0 (it
    counts whole samples from 1.5 periods on): a per-sample caller compares the gap with it
    and calls :func:`skipped` only above it."""
    return 1.25e9 / rate_hz


__all__ = ["Answerer", "StampResponder", "Verdict", "skip_free_ns", "skipped"]
