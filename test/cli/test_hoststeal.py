"""The machine's steal time over a span, read from /proc/stat."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcsms_ros.cli.hoststeal import (
    CpuTimes,
    busy_fraction,
    percents,
    read_cpu_times,
    steal_fraction,
)

#: A 2-CPU machine's first lines (user nice system idle iowait irq softirq steal guest gnice).
STAT = "cpu  {user} 2177 14423 81511 190 0 261 {steal} 40 0\ncpu0 1 2 3 4 5 6 7 8 9 10\n"


def _stat(tmp: Path, name: str, user: int, steal: int) -> Path:
    p = tmp / name
    p.write_text(STAT.format(user=user, steal=steal))
    return p


def test_the_counters_are_the_first_line_without_the_guest_fields(tmp_path: Path) -> None:
    """Steal is the 8th field; the total sums the first eight (guest time is already in user)."""
    t = read_cpu_times(_stat(tmp_path, "a", 63237, 882))
    assert t == CpuTimes(steal=882, idle=81511 + 190,
                         total=63237 + 2177 + 14423 + 81511 + 190 + 0 + 261 + 882)


def test_the_share_stolen_is_steal_over_every_tick_between_two_reads(tmp_path: Path) -> None:
    """1,000 ticks pass, 900 of them user and 100 steal: 10 %."""
    a = read_cpu_times(_stat(tmp_path, "a", 63237, 882))
    b = read_cpu_times(_stat(tmp_path, "b", 63237 + 900, 982))
    assert steal_fraction(a, b) == pytest.approx(0.1)
    assert steal_fraction(a, a) is None  # no tick passed
    assert steal_fraction(None, b) is None and steal_fraction(a, None) is None


def test_the_busy_share_is_every_tick_but_idle_and_iowait(tmp_path: Path) -> None:
    """1,000 ticks pass, 900 user and 100 steal, none idle: all busy; then 500 idle of 1,000."""
    a = read_cpu_times(_stat(tmp_path, "a", 63237, 882))
    b = read_cpu_times(_stat(tmp_path, "b", 63237 + 900, 982))
    assert busy_fraction(a, b) == pytest.approx(1.0)
    p = tmp_path / "c"
    p.write_text(STAT.format(user=63237 + 1400, steal=982).replace(" 81511 ", " 82011 "))
    c = read_cpu_times(p)
    assert busy_fraction(b, c) == pytest.approx(0.5)
    assert busy_fraction(a, a) is None and busy_fraction(None, b) is None


def test_percents_join_known_and_unknown_shares() -> None:
    assert percents([0.0123, None, 1.0]) == "1.2 / ? / 100.0"
    assert percents([0.5], digits=0) == "50"


@pytest.mark.parametrize("text", ["", "cpu 1 2 3\n", "intr 1 2 3 4 5 6 7 8 9\n",
                                  "cpu a b c d e f g h\n"])
def test_a_file_without_the_fields_gives_none(tmp_path: Path, text: str) -> None:
    """An old kernel (no steal field), another file or a missing one: not known, no error."""
    p = tmp_path / "stat"
    p.write_text(text)
    assert read_cpu_times(p) is None
    assert read_cpu_times(tmp_path / "absent") is None


def test_this_machine_counts_forward() -> None:
    """On Linux the real counters are read and only grow; the share is a fraction."""
    a = read_cpu_times()
    if a is None:
        pytest.skip("no /proc/stat with a steal field")
    sum(i * i for i in range(300000))  # let a tick pass
    b = read_cpu_times()
    assert b is not None and b.total >= a.total and b.steal >= a.steal
    share = steal_fraction(a, b)
    assert share is None or 0.0 <= share <= 1.0
