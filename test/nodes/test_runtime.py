"""Node process start-up: the opt-in SCHED_FIFO priority of the control path."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from dcsms_ros.graph import define_graph
from dcsms_ros.nodes.deploy import children
from dcsms_ros.nodes.runtime import RT_PRIORITY_ENV

_PROBE = ("import os; from dcsms_ros.nodes.runtime import apply_rt_priority as a; w = a(); "
          "print(repr(w)); print(os.sched_getscheduler(0) == os.SCHED_FIFO, "
          "os.sched_getparam(0).sched_priority)")


def _probe(value: str | None) -> tuple[str, bool, int]:
    env = {k: v for k, v in os.environ.items() if k != RT_PRIORITY_ENV}
    if value is not None:
        env[RT_PRIORITY_ENV] = value
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                         text=True, check=True, timeout=60).stdout.splitlines()
    fifo, prio = out[1].split()
    return out[0], fifo == "True", int(prio)


@pytest.mark.parametrize("value", [None, "0"])
def test_default_scheduler_when_unset_or_zero(value: str | None) -> None:
    """No variable (or 0): the process keeps the default scheduler and says nothing."""
    warning, fifo, _ = _probe(value)
    assert warning == "None" and not fifo


@pytest.mark.parametrize("value", ["abc", "100", "-3"])
def test_bad_priority_is_a_warning_not_a_crash(value: str) -> None:
    """A value outside 1..99 is named in a warning; the scheduler is left alone."""
    warning, fifo, _ = _probe(value)
    assert "1..99" in warning and value in warning and not fifo


def test_valid_priority_is_applied_or_refused_aloud() -> None:
    """Priority 7: SCHED_FIFO at 7 where permitted (root, CAP_SYS_NICE), else a warning."""
    warning, fifo, prio = _probe("7")
    if fifo:
        assert warning == "None" and prio == 7
    else:
        assert "refused" in warning


def test_rt_priority_covers_only_the_control_path(tmp_path, cfg) -> None:
    """--rt-priority: plant, decoupling and controllers; not mode_switch (nor the recorder)."""
    kids = children(define_graph(cfg), tmp_path / "params.yaml", rt_priority=50)
    got = {k.name: k.env.get(RT_PRIORITY_ENV) for k in kids}
    assert got == {"mode_switch": None, "fb_stage1": "50", "fb_stage2": "50", "ff_stage1": "50",
                   "sensor_decoupling": "50", "plant_simulator": "50"}
