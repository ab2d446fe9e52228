"""First-sample gate with a fake clock."""

from __future__ import annotations

from dcsms_ros.protocols.gate import FirstSampleGate


def test_opens_when_matched_and_stays_open() -> None:
    g = FirstSampleGate(closed=True, timeout_s=5.0)
    matched = [False]
    assert not g.ready(lambda: matched[0], 0.0)
    assert not g.ready(lambda: matched[0], 4.0)
    matched[0] = True
    assert g.ready(lambda: matched[0], 4.5) and not g.timed_out
    matched[0] = False
    assert g.ready(lambda: matched[0], 4.6)  # once open, open


def test_times_out_and_says_so() -> None:
    g = FirstSampleGate(closed=True, timeout_s=5.0)
    assert not g.ready(lambda: False, 100.0)
    assert g.ready(lambda: False, 105.1) and g.timed_out


def test_real_time_is_open_from_the_start() -> None:
    g = FirstSampleGate(closed=False)
    assert g.ready(lambda: False, 0.0) and not g.timed_out
