"""The graph against the batch engine, bit for bit: composed lockstep with a mode schedule (in
its own namespace), and a lockstep run that trips, one process per node and composed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode, controller_ids

DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]
TIMEOUT_S = 400.0


def _sim(args: list[str], log: Path) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([*DCSMS, "sim", *args], capture_output=True, text=True,
                          timeout=TIMEOUT_S, check=False)
    log.write_text(proc.stdout + proc.stderr)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "Traceback" not in proc.stdout + proc.stderr
    return proc


def _read(bag: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with Reader(bag) as r:
        for c, t, raw in r.messages():
            out.setdefault(c.topic, []).append((t, bytes(raw)))
    return out


def _series(msgs: list[tuple[int, bytes]], msgtype: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, values) of a stream, one per stamp (a retransmission repeats its values)."""
    b = cdr.decode_batch(msgtype, [m for _, m in msgs])
    key = {cdr.TWIST_STAMPED: "twist", cdr.WRENCH_STAMPED: "wrench"}.get(msgtype)
    vals = b.fields[key] if key else np.concatenate(
        [b.fields["velocity"], b.fields["effort"]], axis=1)
    stamps, first = np.unique(b.stamp_ns, return_index=True)
    for s, v in zip(b.stamp_ns, vals, strict=True):  # repeats carry the same numbers
        np.testing.assert_array_equal(v, vals[first[np.searchsorted(stamps, s)]])
    return stamps, vals[first]


def _streams(n: int) -> dict[str, str]:
    s = {topics.SENSORS_RAW: cdr.JOINT_STATE, topics.ACTUATORS_APPLIED: cdr.JOINT_STATE}
    for b in topics.body_names(n):
        s[topics.velocity_topic(b)] = s[topics.truth_topic(b)] = cdr.TWIST_STAMPED
    s.update({topics.force_topic(c): cdr.WRENCH_STAMPED for c in controller_ids(n)})
    return s


def _modes(msgs: list[tuple[int, bytes]]) -> list[str]:
    return [cdr.decode_string(m) for _, m in msgs]


def test_composed_schedule_equals_batch(domain: int, cfg: SystemConfig, tmp_path: Path) -> None:
    """`sim --engine graph --composed --schedule` in namespace /t13, recorded by a recorder
    process (a subscriber outside the composed process: every message goes to it over DDS),
    writes the same numbers, stamps and mode sequence as `--engine batch`: every switch went
    through the set_mode services and landed on its scheduled sample."""
    common = ["--mode", "passive", "--duration", "1.2", "--seed", "5",
              "--schedule", "0.3:dfbc_ffc,0.7:fbc"]
    graph, batch = tmp_path / "graph", tmp_path / "batch"
    g = _sim([*common, "--engine", "graph", "--composed", "--recorder", "process",
              "--namespace", "/t13",
              "--out", str(graph)], tmp_path / "graph.log")
    _sim([*common, "--engine", "batch", "--out", str(batch)], tmp_path / "batch.log")
    got, ref = _read(graph), _read(batch)
    k = int(round(1.2 * cfg.plant.rate_hz))
    for topic, msgtype in _streams(cfg.plant.num_stages).items():
        mine = "/t13" + topic.removeprefix(topics.NAMESPACE)
        gs, gv = _series(got[mine], msgtype)
        bs, bv = _series(ref[topic], msgtype)
        assert gs.size == bs.size == k, (topic, gs.size)
        np.testing.assert_array_equal(gs, bs, err_msg=topic)
        np.testing.assert_array_equal(gv, bv, err_msg=topic)
    assert _modes(got["/t13/mode"]) == _modes(ref[topics.MODE]) == ["Passive", "DFBC+FFC", "FBC"]
    # the supervisor took each switch on the same sample (the graph adds its start state)
    assert _modes(got["/t13/supervisor/state"])[1:] == _modes(ref[topics.SUPERVISOR_STATE]) == [
        "ENGAGED DFBC+FFC at 0.2995 s: user set DFBC+FFC", "ENGAGED FBC at 0.6995 s: user set FBC"]
    assert not any(t.startswith(topics.NAMESPACE + "/") for t in got), sorted(got)
    print(f"\ncomposed schedule run: {g.stdout.strip().splitlines()[-1]}")


def _unstable(cfg: SystemConfig) -> SystemConfig:
    gain = [50.0 * g for g in cfg.params["feedback.stage2.gain"]]
    return with_overrides(cfg, {"feedback.stage2.gain": gain})


@pytest.mark.parametrize("composed, supervised", [(True, True), (False, True), (True, False)],
                         ids=["composed", "per-process", "no-supervisor"])
def test_lockstep_trip_lands_on_the_batch_sample(composed: bool, supervised: bool, domain: int,
                                                 cfg: SystemConfig, tmp_path: Path) -> None:
    """DFBC with the stage-2 gain x50: the graph trips at the batch engine's checkpoint
    (sample 99), goes Passive from sample 100 (the controllers fade out from there), and
    every number equals simulate() bit for bit; the supervisor's transitions are recorded
    with the batch engine's samples (``--no-supervisor``: the plain latch)."""
    bad = _unstable(cfg)
    gain = "[" + ",".join(repr(x) for x in bad.params["feedback.stage2.gain"]) + "]"
    out = tmp_path / "bag"
    # --allow-unstable: the initial mode passes the stability guard, and this one must trip
    _sim(["--engine", "graph", "--mode", "dfbc", "--duration", "0.3", "--out", str(out),
          "--set", f"feedback.stage2.gain={gain}", "--allow-unstable",
          *(["--composed"] if composed else []), *([] if supervised else ["--no-supervisor"])],
         tmp_path / "sim.log")
    if not supervised:
        bad = with_overrides(bad, {"supervisor.enabled": False})
    ref = simulate(bad, Mode.DFBC, 0.3, allow_unstable=True)
    first = ref.supervision[0].sample if supervised else (ref.trip.sample if ref.trip else -1)
    assert first == 99
    assert ref.mode == [(0, "DFBC"), (100, "Passive")]
    got = _read(out)
    for c in controller_ids(cfg.plant.num_stages):
        stamps, w = _series(got[topics.force_topic(c)], cdr.WRENCH_STAMPED)
        assert stamps.size == 600
        np.testing.assert_array_equal(w[:, 2], ref.wrench[c][:, 0], err_msg=c)
    _, applied = _series(got[topics.ACTUATORS_APPLIED], cdr.JOINT_STATE)
    np.testing.assert_array_equal(applied, ref.applied)
    assert _modes(got[topics.MODE]) == ["DFBC", "Passive"]
    states = _modes(got[topics.SUPERVISOR_STATE])
    if supervised:
        assert states == ["ENGAGED DFBC at 0.0000 s: start",
                          *(tr.label for tr in ref.supervision)], states
        assert states[1].startswith("TRIPPED Passive at 0.0495 s: ")
    else:  # the plain latch is on the state topic too (an excitation stops on it)
        assert ref.trip is not None
        assert states == ["OFF DFBC at 0.0000 s: supervisor disabled",
                          f"LATCHED Passive at 0.0495 s: {ref.trip.reason} (no supervisor)"]
