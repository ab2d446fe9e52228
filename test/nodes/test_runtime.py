"""Node process start-up: the opt-in SCHED_FIFO priority of the control path."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from dcsms_ros.graph import define_graph
from dcsms_ros.nodes.deploy import children
from dcsms_ros.nodes.runtime import RT_PRIORITY_ENV, rt_priority_from_env

# A real node process: DDS threads exist, one more thread plays the hot thread; prints each
# thread's name, whether it is the hot one, its policy and priority.
_PROBE = """
import os, threading, time, rclpy
from rclpy.context import Context
from dcsms_ros.nodes.runtime import place_threads
ctx = Context(); rclpy.init(context=ctx)
node = rclpy.create_node("probe", context=ctx)
hot = threading.Thread(target=time.sleep, args=(3,), daemon=True); hot.start()
print(repr(place_threads(7, hot.native_id)))
for t in os.listdir("/proc/self/task"):
    name = open(f"/proc/self/task/{t}/comm").read().strip()
    print(name.replace(" ", "_"), int(t) == hot.native_id, os.sched_getscheduler(int(t)),
          os.sched_getparam(int(t)).sched_priority)
"""


@pytest.mark.parametrize("value, prio", [(None, 0), ("0", 0), ("7", 7), ("99", 99)])
def test_priority_from_env(monkeypatch, value: str | None, prio: int) -> None:
    """Unset or 0: off, silently; 1..99: that priority."""
    if value is None:
        monkeypatch.delenv(RT_PRIORITY_ENV, raising=False)
    else:
        monkeypatch.setenv(RT_PRIORITY_ENV, value)
    assert rt_priority_from_env() == (prio, None)


@pytest.mark.parametrize("value", ["abc", "100", "-3"])
def test_bad_priority_is_a_warning_not_a_crash(monkeypatch, value: str) -> None:
    """A value outside 1..99 is named in a warning and turns real time off."""
    monkeypatch.setenv(RT_PRIORITY_ENV, value)
    prio, warning = rt_priority_from_env()
    assert prio == 0 and warning is not None and "1..99" in warning and value in warning


def test_only_the_hot_thread_and_dds_receive_threads_are_real_time() -> None:
    """Priority 7: the hot thread FIFO 7, Fast DDS's receive threads FIFO 6, every other thread
    (the main/executor thread, DDS event and discovery threads) on the default scheduler - or
    a warning where SCHED_FIFO is not permitted."""
    env = {k: v for k, v in os.environ.items() if k != RT_PRIORITY_ENV}
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                         text=True, check=True, timeout=60).stdout.splitlines()
    if out[0] != "None":
        assert "refused" in out[0]
        return
    rows = [line.split() for line in out[1:]]
    got = {(name, is_hot == "True"): (int(pol), int(prio)) for name, is_hot, pol, prio in rows}
    receive = [k for k in got if re.fullmatch(r"dds\.(shm|udp)\.\d+", k[0])]
    assert receive, f"no DDS receive thread among {sorted(got)}"
    for key, (pol, prio) in got.items():
        if key[1]:
            assert (pol, prio) == (os.SCHED_FIFO, 7)
        elif key in receive:
            assert (pol, prio) == (os.SCHED_FIFO, 6), key
        else:
            assert pol == os.SCHED_OTHER, key


def test_rt_priority_covers_only_the_control_path(tmp_path, cfg) -> None:
    """--rt-priority: plant, decoupling and controllers; not mode_switch (nor the recorder)."""
    kids = children(define_graph(cfg), tmp_path / "params.yaml", rt_priority=50)
    got = {k.name: k.env.get(RT_PRIORITY_ENV) for k in kids}
    assert got == {"mode_switch": None, "fb_stage1": "50", "fb_stage2": "50", "ff_stage1": "50",
                   "sensor_decoupling": "50", "plant_simulator": "50"}
