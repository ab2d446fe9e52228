"""First-sample gate: hold the first lockstep answer until every reader is matched.

A sample published before a reader's DDS endpoint matched is lost to that reader for good
(volatile streams), so in lockstep a node answers its first sample only once its publishers
matched every reader it knows of (the plant republishes the sample meanwhile), or after
``timeout_s`` (an incompatible reader must not stall the graph). In real time the gate is open
from the start.
"""

from __future__ import annotations

from collections.abc import Callable

#: Longest hold of the first lockstep answer while readers match, s.
MATCH_TIMEOUT_S = 5.0


class FirstSampleGate:
    """Closed until ``matched()`` is true once, or ``timeout_s`` after the first try.

    Attributes
    ----------
    open : bool
    timed_out : bool
        True if it opened by the timeout (the caller logs it).
    """

    def __init__(self, closed: bool, timeout_s: float = MATCH_TIMEOUT_S) -> None:
        self.open = not closed
        self.timeout_s = timeout_s
        self.timed_out = False
        self._t0: float | None = None

    def ready(self, matched: Callable[[], bool], now: float) -> bool:
        """True once the first answer may go out (then always); ``now`` in s."""
        if self.open:
            return True
        if self._t0 is None:
            self._t0 = now
        self.open = bool(matched())
        if not self.open and now - self._t0 > self.timeout_s:
            self.open = self.timed_out = True
        return self.open


__all__ = ["MATCH_TIMEOUT_S", "FirstSampleGate"]
