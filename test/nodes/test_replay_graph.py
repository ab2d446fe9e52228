"""Ground replay through the live graph: a recorded floor drives the plant node."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from dcsms_ros.analysis.export import write_result_bag
from dcsms_ros.analysis.replay import load_ground, read_twists
from dcsms_ros.core import topics
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode

DURATION_S = 0.5


def test_graph_replays_a_recorded_ground_like_the_batch_engine(domain, cfg, tmp_path):
    """`dcsms sim --engine graph --ground-from BAG` equals the batch engine fed the same floor."""
    floor = tmp_path / "floor"
    write_result_bag(simulate(cfg, Mode.PASSIVE, 1.0, seed=7), floor)
    out = tmp_path / "replayed"
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "sim", "--engine", "graph", "--mode", "FBC",
           "--duration", str(DURATION_S), "--ground-from", str(floor), "--out", str(out)]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=240, check=False)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Traceback" not in run.stderr
    ground = load_ground(floor, None, cfg.plant.rate_hz, cfg.plant.dof)
    ref = simulate(cfg, Mode.FBC, DURATION_S, ground=ground)
    k = ref.t.size
    for i, body in enumerate(topics.body_names(cfg.plant.num_stages)):
        _, stamps, values = read_twists(out, topics.truth_topic(body))
        _, first = np.unique(stamps, return_index=True)  # a lockstep retry repeats a stamp
        np.testing.assert_array_equal(values[first][:k, 2], ref.truth[:, i, 0], err_msg=body)
    np.testing.assert_array_equal(ref.truth[:, 0, 0], ground[:k, 0])
