"""Per-sample answers keyed by the input's stamp: compute once, repeat from the cache.

In lockstep the plant republishes a sample whose answers are missing; a node that already
answered it must not step its filters again, so a repeated stamp gets the cached answer. A
stamp older than the newest answered one is dropped (out of order). Only a new stamp is
computed.
"""

from __future__ import annotations

import enum
from typing import Generic, TypeVar

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

    def store(self, stamp_ns: int, answer: T) -> T:
        """Remember ``answer`` to the input stamped ``stamp_ns``; returns it."""
        self.last_ns = stamp_ns
        self.cache = answer
        return answer


__all__ = ["StampResponder", "Verdict"]
