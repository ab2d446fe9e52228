"""Stamps of samples. The nodes build no message objects: the per-sample messages and the
``/diagnostics`` reports are serialised by :mod:`dcsms_ros.cdr`. Stamps are integer
nanoseconds so that lockstep matching is exact.
"""

from __future__ import annotations

from dcsms_ros.cdr import NS


def sample_ns(k: int, rate_hz: float) -> int:
    """Stamp of sample ``k`` at ``rate_hz``: ``round(k / rate_hz)`` in ns (exact, no drift)."""
    return int(round(k * NS / rate_hz))
