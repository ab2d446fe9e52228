"""`bench/gil_probe.py`: the attribution of late samples, and one probed composed run."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("gil_probe", ROOT / "bench" / "gil_probe.py")
assert _spec is not None and _spec.loader is not None
gil_probe = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gil_probe)

T = 5e-4  # 2 kHz


def _log():
    # three late bursts at 1.0 s (3 samples, during a callback), 2.0 s (2 samples, the
    # executor outside its wait without a callback) and 3.0 s (4 samples, executor waiting);
    # on-time steps elsewhere
    due = [(k * T + 1e-5, k * T, 1, T) for k in range(0, 8000, 7)]
    due += [(1.0 + 2e-4, 1.0, 3, T), (2.0 + 1e-4, 2.0, 2, T), (3.0 + 1e-4, 3.0, 4, T)]
    cbs = [(0.998, 1.0002, 1.5e-3, "Judge.timer"),    # overlaps the burst's window
           (1.5, 1.501, 8e-4, "Node.report")]         # overlaps none
    waits = [(0.0, 0.998, 0.00), (1.0003, 1.999, 0.01),   # busy (no wait) 1.999-2.0001
             (2.0001, 4.0, 0.02)]                         # the 3.0 s burst: waiting
    return {"due": due, "cb": cbs, "wait": waits}


@pytest.mark.unit
def test_attribute_counts_each_burst_once_by_what_the_executor_did():
    res = gil_probe.attribute(_log())
    assert res["late"] == 2 + 1 + 3
    assert res["causes"] == {"Judge.timer": 2, gil_probe.BUSY: 1, gil_probe.IDLE: 3}
    assert sum(res["causes"].values()) == res["late"]
    assert res["callbacks"]["Node.report"]["calls"] == 1
    assert res["callbacks"]["Judge.timer"]["cpu_us"] == pytest.approx(1500.0)
    ex = res["executor"]
    assert ex["wakes_per_s"] == pytest.approx(3 / 3.002, rel=1e-6)
    assert ex["cpu_share"] == pytest.approx(0.02 / 3.002, rel=1e-6)


@pytest.mark.unit
def test_attribute_without_late_steps():
    log = _log()
    log["due"] = [d for d in log["due"] if d[2] == 1]
    res = gil_probe.attribute(log)
    assert res["late"] == 0 and res["causes"] == {}
    assert 0.0 < res["lateness_ms"]["p50"] < 0.1


@pytest.mark.unit
def test_a_last_burst_past_the_runs_end_steps_only_the_samples_of_the_run():
    """The pacer may count two samples due at the last step of a 3 s run; the plant stops at
    sample 6000 (a CI run reported 6001 stepped)."""
    due = [(k * T + 1e-5, k * T, 1, T) for k in range(5999)]
    due.append((5999 * T + T + 1e-5, 6000 * T, 2, T))
    assert gil_probe.attribute({"due": due, "cb": [], "wait": []})["samples_stepped"] == 6001
    assert gil_probe.attribute({"due": due, "cb": [], "wait": []},
                               seconds=3.0)["samples_stepped"] == 6000


@pytest.mark.ros
@pytest.mark.slow
def test_probe_runs_a_composed_real_time_graph(tmp_path, domain):
    """A 3 s probed run: every late sample the pacer stepped is attributed, the executor's
    thread was seen waking, and the run's own summary line is reported."""
    out = tmp_path / "probe.json"
    p = subprocess.run([sys.executable, str(ROOT / "bench" / "gil_probe.py"), "--seconds", "3",
                        "--domain", str(domain), "--json", str(out)],
                       capture_output=True, text=True, timeout=300, check=False)
    assert p.returncode == 0, p.stderr[-2000:]
    (run,) = json.loads(out.read_text())
    assert "summary: samples 6000" in run["summary"]
    assert run["samples_stepped"] == 6000
    assert sum(run["causes"].values()) == run["late"]
    assert run["executor"]["wakes_per_s"] > 1.0
    assert "Housekeeper._tick" in run["callbacks"]  # the judge, reports and flush ride on it


def test_probe_refuses_a_missing_configuration(tmp_path):
    p = subprocess.run([sys.executable, str(ROOT / "bench" / "gil_probe.py"), "--config",
                        str(tmp_path / "none.yaml")], capture_output=True, text=True, timeout=60,
                       check=False)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "no such configuration" in p.stderr
