"""The supervisor's transitions in a batch bag and the analysis timeline read back from it:
table1 DFBC+FFC under the preset's floor with a burst 3000x stronger from 8 to 14 s, run with
the supervisor, exported to a real bag; the timeline is compared with the run's own arrays
(the ground band RMS recomputed here with scipy, the force peaks from ``res.applied``).
The run and its bag take ~12 s of CPU, so those tests are slow; the label parser is not."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from burst import burst_floor, supervisor
from numpy.testing import assert_allclose
from scipy.signal import butter, sosfilt, sosfilt_zi

from dcsms_ros import cdr
from dcsms_ros.analysis import timeline
from dcsms_ros.analysis.bagio import LATCHED_QOS, open_bag
from dcsms_ros.analysis.export import export_result, write_result_bag
from dcsms_ros.analysis.reader import config_from_yaml, read_bag
from dcsms_ros.cli import main
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig, load_config
from dcsms_ros.core.engine import SimResult, Simulation, simulate
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.supervisor import State, Transition

TABLE1 = Path(__file__).resolve().parents[2] / "config" / "table1.yaml"
DURATION_S = 30.0
BURST_S = (8.0, 14.0)


@pytest.fixture(scope="module")
def burst_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimResult, Path]:
    """30 s of table1 DFBC+FFC with the supervisor, the floor x3000 from 8 to 14 s; its bag."""
    cfg = load_config(TABLE1)
    res = Simulation(cfg, Mode.DFBC_FFC, ground=burst_floor(cfg, DURATION_S, *BURST_S),
                     supervisor=supervisor(cfg, Mode.DFBC_FFC)).run(
        int(DURATION_S * cfg.plant.rate_hz))
    assert res is not None
    out = tmp_path_factory.mktemp("timeline") / "burst"
    write_result_bag(res, out)
    return res, out


@pytest.fixture(scope="module")
def read_back(burst_run: tuple[SimResult, Path]) -> timeline.Timeline:
    data = read_bag(burst_run[1])
    assert data.config_text is not None
    tl = timeline.build(data, config_from_yaml(data.config_text))
    assert tl is not None
    return tl


@pytest.mark.slow
def test_the_supervisor_rides_through_the_burst(burst_run: tuple[SimResult, Path]) -> None:
    """The scenario holds: RIDE_THROUGH in the burst, DFBC+FFC back after it, no trip."""
    res, _ = burst_run
    states = [tr.state for tr in res.supervision]
    assert states[0] is State.RIDE_THROUGH, res.supervision
    assert BURST_S[0] <= res.supervision[0].t_s < BURST_S[0] + 0.2
    assert State.TRIPPED not in states and State.LATCHED not in states, res.supervision
    assert states[-1] is State.ENGAGED and res.mode[-1][1] == Mode.DFBC_FFC.label


@pytest.mark.slow
def test_bag_holds_every_transition_at_its_sample(burst_run: tuple[SimResult, Path]) -> None:
    """One supervisor/state String per transition, its text the label, its bag time the
    transition's sample time."""
    res, bag = burst_run
    data = read_bag(bag)
    assert data.counts[topics.SUPERVISOR_STATE] == len(res.supervision)
    assert [text for _, text in data.states] == [tr.label for tr in res.supervision]
    dt_ns = round(res.cfg.plant.dt * 1e9)
    assert [t for t, _ in data.states] == [tr.sample * dt_ns for tr in res.supervision]


@pytest.mark.slow
def test_transitions_read_back_equal_the_run(burst_run: tuple[SimResult, Path],
                                             read_back: timeline.Timeline) -> None:
    res, _ = burst_run
    tl = read_back
    assert [e.state for e in tl.transitions] == [tr.state.value for tr in res.supervision]
    assert [e.mode for e in tl.transitions] == [tr.mode.label for tr in res.supervision]
    assert [e.reason for e in tl.transitions] == [tr.reason for tr in res.supervision]
    # the label carries T with 4 decimals (0.1 ms, a fifth of a 2 kHz sample)
    assert_allclose([e.t_s for e in tl.transitions], [tr.t_s for tr in res.supervision],
                    rtol=0, atol=5e-5)
    assert [lab for _, lab in tl.modes] == [lab for _, lab in res.mode]
    assert_allclose([t for t, _ in tl.modes], [k * res.cfg.plant.dt for k, _ in res.mode],
                    rtol=0, atol=1e-9)


def _windows(x: np.ndarray, n: int) -> np.ndarray:
    """(K, ...) -> (K // n, n, ...): whole windows of n samples."""
    m = x.shape[0] // n
    return x[:m * n].reshape(m, n, *x.shape[1:])


@pytest.mark.slow
def test_ground_blrms_equals_an_independent_estimate(burst_run: tuple[SimResult, Path],
                                                     read_back: timeline.Timeline) -> None:
    """Every 1 s row's ground band RMS against scipy's band-pass of the run's decoupled ground
    velocity (float64; the bag holds float32); the burst windows 3000x louder."""
    res, _ = burst_run
    cfg: SystemConfig = res.cfg
    fs = cfg.plant.rate_hz
    sos = butter(2, list(cfg.control.trip_band_hz), btype="bandpass", fs=fs, output="sos")
    x = res.velocity[:, 0, 0]
    y, _ = sosfilt(sos, x, zi=sosfilt_zi(sos) * x[0])
    want = np.sqrt(np.mean(_windows(y, int(fs)) ** 2, axis=1))
    rows = read_back.rows
    assert len(rows) == int(DURATION_S) and all(r.samples == int(fs) for r in rows)
    got = np.array([r.ground_blrms_mps[0] for r in rows])
    assert_allclose(got, want, rtol=1e-4)
    burst = slice(int(BURST_S[0]), int(BURST_S[1]))
    quiet = np.r_[got[:int(BURST_S[0])], got[int(BURST_S[1]) + 1:]]
    assert_allclose(np.median(got[burst]) / np.median(quiet), 3000.0, rtol=0.1)


@pytest.mark.slow
def test_ground_blrms_scatter_matches_its_standard_deviation(read_back: timeline.Timeline
                                                             ) -> None:
    """Away from the burst (and the decoupled ground's ring-down in the 4 s after it: the
    geophone correction), the floor is stationary: the 1 s rows scatter as their own
    equivalent degrees of freedom say. 20 windows: the scatter's own relative error is
    ~1/sqrt(2 * 19) = 16 %, so 0.6-1.6 is about 3 of it either way."""
    rows = [r for r in read_back.rows if r.t1_s <= BURST_S[0] or r.t0_s >= BURST_S[1] + 4.0]
    assert len(rows) == 20
    g = np.array([r.loudest() for r in rows])
    predicted = np.median([r.ground_rel_std() for r in rows])
    assert 0.6 < (np.std(g, ddof=1) / np.mean(g)) / predicted < 1.6, (g, predicted)


@pytest.mark.slow
def test_force_peaks_equal_the_applied_forces(burst_run: tuple[SimResult, Path],
                                              read_back: timeline.Timeline) -> None:
    """Peak |applied| per 1 s window, N and as a fraction of each actuator's limit."""
    res, _ = burst_run
    fs = int(res.cfg.plant.rate_hz)
    peaks = np.abs(_windows(res.applied, fs)).max(axis=1)  # (windows, actuators)
    limit = np.asarray(read_back.limits_n)
    # 1-DOF: one lumped channel per stage, its coils' limits summed
    assert_allclose(limit, [st.actuator_count * res.cfg.actuators.force_limit_n
                            for st in res.cfg.plant.stages])
    assert_allclose([r.force_peak_n for r in read_back.rows], peaks.max(axis=1), rtol=1e-6)
    assert_allclose([r.force_fraction for r in read_back.rows], (peaks / limit).max(axis=1),
                    rtol=1e-6)


@pytest.mark.slow
def test_rows_carry_mode_and_state(read_back: timeline.Timeline) -> None:
    """Each row: the mode and state at its end; the burst rows ride through in FBC."""
    rows = read_back.rows
    assert (rows[0].mode, rows[0].state) == ("DFBC+FFC", None)
    assert all((r.mode, r.state) == ("FBC", "RIDE_THROUGH")
               for r in rows[int(BURST_S[0]):int(BURST_S[1])])
    assert (rows[-1].mode, rows[-1].state) == ("DFBC+FFC", "ENGAGED")
    assert sum(r.changes for r in rows) == len(read_back.transitions) + len(read_back.modes) - 1
    shown = read_back.condensed()
    assert shown[0] is rows[0] and shown[-1] is rows[-1]
    assert all(r in shown for r in rows if r.changes)


def test_transition_time_comes_from_the_text(tmp_path: Path) -> None:
    """A recorder on another clock: bag times 1000 s late, a transient-local text delivered
    twice, a text that is no transition; the timeline places each transition at its T, once,
    and warns about the other text."""
    cfg = load_config(TABLE1)
    res = simulate(cfg, Mode.DFBC_FFC, 3.0)
    texts = [Transition(1999, 0.9995, State.RIDE_THROUGH, Mode.FBC, "loud").label,
             Transition(3999, 1.9995, State.RECOVERING, Mode.DFBC_FFC, "quiet").label]
    late = 1_000_000_000_000
    with open_bag(tmp_path / "bag") as w:
        export_result(res, w)
        w.add_topic(topics.SUPERVISOR_STATE, cdr.STRING, LATCHED_QOS)
        for t_ns, text in [(late, texts[0]), (late + 5, texts[0]), (late + 7, "hello"),
                           (late + 9, texts[1])]:
            w.write(topics.SUPERVISOR_STATE, t_ns, cdr.encode_string(text))
    tl = timeline.build(read_bag(tmp_path / "bag"), cfg)
    assert tl is not None
    assert [(e.t_s, e.state) for e in tl.transitions] == [(0.9995, "RIDE_THROUGH"),
                                                         (1.9995, "RECOVERING")]
    # state at each window's end, transitions inside it
    assert [(r.state, r.changes) for r in tl.rows] == [("RIDE_THROUGH", 1), ("RECOVERING", 1),
                                                       ("RECOVERING", 0)]
    assert all(r.mode == "DFBC+FFC" for r in tl.rows)  # the bag's own /dcsms/mode
    (warning,) = tl.warnings
    assert "'hello'" in warning


@pytest.mark.parametrize("state", list(State))
def test_label_parses_back(state: State) -> None:
    tr = Transition(812, 0.406, state, Mode.DFBC_FFC, "ground band RMS 0.0012 m/s: loud")
    assert timeline.parse_transition(tr.label) == timeline.Event(
        0.406, state.value, "DFBC+FFC", "ground band RMS 0.0012 m/s: loud")


@pytest.mark.parametrize("text", ["", "ENGAGED", "ENGAGED FBC at x s: y", "engaged FBC at 1 s: y",
                                  "ENGAGED FBC 1.0 s: y"])
def test_other_texts_are_not_transitions(text: str) -> None:
    assert timeline.parse_transition(text) is None


@pytest.mark.slow
def test_analyze_json_and_report_have_the_timeline(burst_run: tuple[SimResult, Path],
                                                   tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    res, bag = burst_run
    assert main(["analyze", str(bag), "--json", "--timeline-window", "2"]) == 0
    (tl,) = json.loads(capsys.readouterr().out)["timeline"]
    assert tl["bag"] == str(bag) and tl["window_s"] == 2.0 and len(tl["rows"]) == 15
    assert [(e["state"], e["mode"]) for e in tl["transitions"]] == [
        (tr.state.value, tr.mode.label) for tr in res.supervision]
    assert main(["analyze", str(bag), "--out", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    assert "RIDE_THROUGH FBC" in text
    report = (tmp_path / "out" / "report.md").read_text()
    assert "## Timeline" in report and "| RIDE_THROUGH | FBC |" in report


@pytest.mark.slow
def test_no_timeline_without_switches_or_supervisor(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """A bag with one mode and no supervisor topic: the output is as before."""
    res = simulate(load_config(TABLE1), Mode.PASSIVE, 12.0)
    write_result_bag(res, tmp_path / "plain")
    assert main(["analyze", str(tmp_path / "plain"), "--json"]) == 0
    assert "timeline" not in json.loads(capsys.readouterr().out)
    assert main(["analyze", str(tmp_path / "plain"), "--out", str(tmp_path / "o")]) == 0
    assert "## Timeline" not in (tmp_path / "o" / "report.md").read_text()


@pytest.mark.parametrize("window", ["0", "-1", "nan"])
def test_bad_window_is_a_usage_error(window: str, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Refused before any bag is read or anything written."""
    assert main(["analyze", str(tmp_path / "bag"), "--timeline-window", window,
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dcsms: error: timeline window ") and err.endswith(": must be > 0\n")
    assert not (tmp_path / "o").exists()
