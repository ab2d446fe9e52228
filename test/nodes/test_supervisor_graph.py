"""The supervisor in the lockstep graph against the batch engine: a replayed floor with a
burst (``--ground-from``) takes table1's DFBC+FFC through RIDE_THROUGH, RECOVERING and back
to ENGAGED; every transition lands on the batch engine's sample and every force is equal bit
for bit. A user's switch to a more active mode during RIDE_THROUGH is refused with the reason
(docs/reliability.md: the supervisor wins until the floor is quiet)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis import timeline
from dcsms_ros.analysis.export import write_result_bag
from dcsms_ros.analysis.reader import config_from_yaml, read_bag
from dcsms_ros.analysis.replay import load_ground
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode, controller_ids
from dcsms_ros.core.supervisor import State
from dcsms_ros.protocols.runstats import LATE_WARN

DURATION_S = 3.5
QUICK = {"supervisor.recover_after_s": 0.5, "supervisor.settle_s": 0.3}


def _burst_bag(cfg: SystemConfig, path: Path) -> None:
    """A floor bag: the preset's own ground, x300 from 0.5 to 1.2 s (ground band RMS ~1e-3 m/s,
    5x the ride-through threshold)."""
    quiet = simulate(cfg, Mode.PASSIVE, 8.5, seed=5, trip=False)
    ground = quiet.truth[:, 0].copy()
    fs = cfg.plant.rate_hz
    ground[int(0.5 * fs):int(1.2 * fs)] *= 300.0
    write_result_bag(simulate(cfg, Mode.PASSIVE, 8.5, ground=ground, trip=False), path)


def _read(bag: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    with Reader(bag) as r:
        for c, _, raw in r.messages():
            out.setdefault(c.topic, []).append(bytes(raw))
    return out


@pytest.mark.slow
def test_graph_rides_through_a_replayed_burst_like_the_batch_engine(domain: int,
                                                                    cfg: SystemConfig,
                                                                    tmp_path: Path) -> None:
    floor = tmp_path / "floor"
    _burst_bag(cfg, floor)
    out = tmp_path / "run"
    sets = [x for k, v in QUICK.items() for x in ("--set", f"{k}={v}")]
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "sim", "--engine", "graph", "--composed",
           "--mode", "dfbc_ffc", "--duration", str(DURATION_S), "--ground-from", str(floor),
           "--schedule", "0.8:dfbc", "--out", str(out), *sets]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=400, check=False)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    quick = with_overrides(cfg, QUICK)
    ground = load_ground(floor, None, cfg.plant.rate_hz, cfg.plant.dof)
    ref = simulate(quick, Mode.DFBC_FFC, DURATION_S, ground=ground,
                   schedule=((0.8, Mode.DFBC),))
    assert ref.refused == [(1600, "DFBC")]
    assert "switch to DFBC at t=0.8 s refused: supervisor RIDE_THROUGH" in run.stderr, \
        run.stderr[-2000:]
    states = [tr.state for tr in ref.supervision]
    assert states == [State.RIDE_THROUGH, State.RECOVERING, State.ENGAGED], ref.supervision
    assert ref.mode[-1][1] == Mode.DFBC_FFC.label
    got = _read(out)
    labels = [cdr.decode_string(m) for m in got[topics.SUPERVISOR_STATE]]
    assert labels == ["ENGAGED DFBC+FFC at 0.0000 s: start",
                      *(tr.label for tr in ref.supervision)], labels
    assert [cdr.decode_string(m) for m in got[topics.MODE]] == [m for _, m in ref.mode]
    # the analysis timeline of the graph's bag (wall-clock bag times) reads them back
    data = read_bag(out)
    tl = timeline.build(data, config_from_yaml(data.config_text))
    assert tl is not None
    assert [(e.state, e.mode) for e in tl.transitions] == [
        ("ENGAGED", "DFBC+FFC"), *((tr.state.value, tr.mode.label) for tr in ref.supervision)]
    np.testing.assert_allclose([e.t_s for e in tl.transitions[1:]],
                               [tr.t_s for tr in ref.supervision], atol=1e-4)
    k = ref.t.size
    for c in controller_ids(cfg.plant.num_stages):
        b = cdr.decode_batch(cdr.WRENCH_STAMPED, got[topics.force_topic(c)])
        _, first = np.unique(b.stamp_ns, return_index=True)  # a lockstep retry repeats one
        np.testing.assert_array_equal(b.fields["wrench"][first][:k, 2], ref.wrench[c][:, 0],
                                      err_msg=c)


@pytest.mark.slow
def test_realtime_graph_rides_through_the_burst(domain: int, cfg: SystemConfig,
                                                tmp_path: Path) -> None:
    """Real time (`dcsms up --realtime --composed`), the same replayed burst: RIDE_THROUGH in
    FBC soon after the burst starts (checkpoints every 50 ms of wall time), then back to
    DFBC+FFC, every transition recorded and the mode topic following it."""
    floor = tmp_path / "floor"
    _burst_bag(cfg, floor)
    out = tmp_path / "run"
    sets = [x for k, v in QUICK.items() for x in ("--set", f"{k}={v}")]
    # longer than lockstep's run: on a loaded 2-core box late samples degrade the loop and the
    # stage rings longer after the burst (measured: stage 2 at 0.95 mm/s 1 s after it, at
    # 51 % late samples), so the quiet time comes later
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "up", "--realtime", "--composed", "--mode",
           "dfbc_ffc", "--duration", "8", "--ground-from", str(floor), "--record",
           str(out), "--log-dir", str(tmp_path / "logs"), *sets]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=400, check=False)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    got = _read(out)
    labels = [cdr.decode_string(m) for m in got[topics.SUPERVISOR_STATE]]
    heads = [x.split()[:2] for x in labels]
    # The run's own late fraction says what it can show. A graph that kept real time (<= 1 %
    # late) runs the configured loop: the whole sequence, RIDE_THROUGH within 0.2 s of the
    # burst (it starts at 0.5 s). One that did not ran a loop with more delay: the trip feed
    # judges the decoupled ground stream, which has gaps then (the decoupling answers the newest
    # sample of a catch-up burst), and the loop rings longer. Measured on a slow machine
    # (2026-11-26, 49-77 % late): RIDE_THROUGH at 0.7495 and 1.0995 s, RECOVERING after it in
    # some runs and not within the 8 s in another. There only the ride-through is asserted.
    late = json.loads((tmp_path / "logs" / "summary.json").read_text())["late_fraction"]
    assert heads[:2] == [["ENGAGED", "DFBC+FFC"], ["RIDE_THROUGH", "FBC"]], (late, labels)
    t_ride = float(labels[1].split()[3])
    if late > LATE_WARN:
        assert 0.5 <= t_ride <= 1.5, (late, labels)
        return
    assert heads == [["ENGAGED", "DFBC+FFC"], ["RIDE_THROUGH", "FBC"],
                     ["RECOVERING", "DFBC+FFC"], ["ENGAGED", "DFBC+FFC"]], labels
    assert 0.5 <= t_ride <= 0.7, labels
    assert [cdr.decode_string(m) for m in got[topics.MODE]] == ["DFBC+FFC", "FBC", "DFBC+FFC"]


@pytest.mark.slow
def test_graph_gives_up_on_an_unstable_loop_like_the_batch_engine(domain: int,
                                                                   cfg: SystemConfig,
                                                                   tmp_path: Path) -> None:
    """Table1 DFBC with the stage-2 gain x50, started with --allow-unstable: tripped,
    re-engaged 3 times, then LATCHED with the reason logged; every transition on the batch
    engine's sample."""
    gain = [50.0 * g for g in cfg.params["feedback.stage2.gain"]]
    over = {"feedback.stage2.gain": gain, "supervisor.hold_s": 0.2, "supervisor.settle_s": 0.2}
    sets = ["--set", "feedback.stage2.gain=[" + ",".join(repr(x) for x in gain) + "]",
            "--set", "supervisor.hold_s=0.2", "--set", "supervisor.settle_s=0.2"]
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "sim", "--engine", "graph", "--composed",
           "--mode", "dfbc", "--duration", "16", "--allow-unstable", "--out", str(out), *sets]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    ref = simulate(with_overrides(cfg, over), Mode.DFBC, 16.0, allow_unstable=True)
    states = [tr.state for tr in ref.supervision]
    assert states.count(State.RECOVERING) == 3 and states[-1] is State.LATCHED, ref.supervision
    assert "gave up" in ref.supervision[-1].reason
    labels = [cdr.decode_string(m) for m in _read(out)[topics.SUPERVISOR_STATE]]
    assert labels == ["ENGAGED DFBC at 0.0000 s: start", *(tr.label for tr in ref.supervision)]
    logs = Path(re.search(r"logs in (\S+)", run.stdout).group(1))  # type: ignore[union-attr]
    log = "\n".join(p.read_text() for p in logs.glob("*.log"))
    assert f"supervisor: {ref.supervision[-1].label}" in log
