"""``dcsms sim``: batch run to bag, ground replay from a bag, one-line errors with exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.export import write_result_bag
from dcsms_ros.cli import main
from dcsms_ros.cli.sim import parse_schedule
from dcsms_ros.core.config import load_config
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode


def _twists(bag: Path, topic: str) -> np.ndarray:
    with Reader(bag) as r:
        conns = [c for c in r.connections if c.topic == topic]
        raw = [bytes(d) for _, _, d in r.messages(connections=conns)]
    return cdr.decode_batch(cdr.TWIST_STAMPED, raw).fields["twist"]


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 2 s FBC -> Passive batch bag written by the CLI, with /clock, on SQLite."""
    out = tmp_path_factory.mktemp("sim") / "a"
    assert main(["sim", "--mode", "fbc", "--duration", "2", "--seed", "4", "--out", str(out),
                 "--schedule", "1:passive", "--storage", "sqlite3", "--clock"]) == 0
    return out


def test_sim_writes_bag(bag: Path) -> None:
    """The bag holds the graph's topics (and /clock when asked) with one message per sample."""
    with Reader(bag) as r:
        counts = {c.topic: c.msgcount for c in r.connections}
    assert counts["/dcsms/velocity/stage2"] == counts["/clock"] == 4000
    assert counts["/dcsms/mode"] == 2 and counts["/dcsms/config"] == 1
    # the scheduled switch is a supervisor transition too (ENGAGED Passive: user set Passive)
    assert counts["/dcsms/supervisor/state"] == 1
    assert len(counts) == 15 and next(bag.glob("*.db3"))


def test_ground_from_replays_recorded_ground(bag: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """--ground-from BAG: the new run's true ground is the recorded decoupled ground velocity,
    looped (with a warning) when the recording is shorter than the run."""
    out = tmp_path / "b"
    assert main(["sim", "--duration", "3", "--out", str(out), "--ground-from", str(bag)]) == 0
    captured = capsys.readouterr()
    assert "wrote" in captured.out and "looping" in captured.err
    rec = _twists(bag, "/dcsms/velocity/ground")
    got = _twists(out, "/dcsms/truth/ground")
    np.testing.assert_array_equal(got[:4000], rec)
    np.testing.assert_array_equal(got[4000:], rec[:2000])
    spec = f"{bag}:/dcsms/truth/ground"
    assert main(["sim", "--duration", "1", "--out", str(tmp_path / "c"), "--ground-from",
                 spec]) == 0
    np.testing.assert_array_equal(_twists(tmp_path / "c", "/dcsms/truth/ground"),
                                  _twists(bag, "/dcsms/truth/ground")[:2000])


@pytest.mark.parametrize("extra, message", [
    (["--ground-from", "/nonexistent/bag"], "no such bag"),
    (["--ground-from", "{bag}:/dcsms/nope"], "no topic /dcsms/nope"),
    (["--ground-from", "{bag}:/dcsms/mode"], "expected geometry_msgs/msg/TwistStamped"),
    (["--schedule", "abc"], "expected TIME:MODE"),
    (["--mode", "warp"], "unknown mode"),
    (["--duration", "-1"], "must be > 0"),
    (["--set", "m1=-5"], "stage1.mass"),
    (["--excite", "stage1.z:white:150"], "exceeds the actuator limit"),
    (["--excite", "stage1.z:white:5", "--excite", "stage2.z:white:5"], "one stage"),
    (["--excite", "stage1.z:chirp:5"], "unknown kind"),
    (["--plant-set", "feedback.stage1.gain=[0,0,1,0,0,0]"], "feedback.stage1.gain"),
    (["--plant-set", "m1=-3"], "stage1.mass"),
    (["--engine", "graph", "--plant-set", "m1=900"], "--plant-set is not supported"),
])
def test_bad_input_is_one_line_exit_2(bag: Path, tmp_path: Path, extra: list[str],
                                      message: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Bad bag, topic, schedule, mode, duration or parameter: one line on stderr, exit 2."""
    argv = ["sim", "--duration", "1", "--out", str(tmp_path / "x")]
    argv += [a.format(bag=bag) for a in extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dcsms: error:") and message in err, err
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.partial").exists()


def test_excite_and_plant_set(tmp_path: Path) -> None:
    """--excite writes the excitation the plant added on /dcsms/force/excitation (frame = the
    stage); --plant-set changes the simulated plant but not the recorded configuration."""
    from dcsms_ros.analysis.reader import config_from_yaml
    from dcsms_ros.cli.common import default_config_path
    from dcsms_ros.core.config import load_config, with_overrides
    from dcsms_ros.core.engine import simulate
    from dcsms_ros.core.excitation import excitation_signal, parse_spec

    out = tmp_path / "e"
    assert main(["sim", "--duration", "1", "--seed", "2", "--out", str(out), "--excite",
                 "stage2.z:sweep:10:1-50", "--plant-set", "m1=1100"]) == 0
    with Reader(out) as r:
        conns = [c for c in r.connections if c.topic == "/dcsms/force/excitation"]
        raw = [bytes(d) for _, _, d in r.messages(connections=conns)]
        text = [bytes(d) for c, _, d in r.messages() if c.topic == "/dcsms/config"]
    batch = cdr.decode_batch(cdr.WRENCH_STAMPED, raw)
    cfg = load_config(default_config_path())
    exc = excitation_signal(cfg, [parse_spec("stage2.z:sweep:10:1-50")], 2000, 2)
    assert batch.frame_id == "stage2"
    np.testing.assert_array_equal(batch.fields["wrench"][:, 2], exc[:, 1, 0])
    assert not batch.fields["wrench"][:, [0, 1, 3, 4, 5]].any()
    recorded = config_from_yaml(cdr.decode_string(text[0]))
    assert recorded.plant.stages[0].mass == 988.8
    res = simulate(cfg, Mode.PASSIVE, 1.0, seed=2, excite=exc,
                   plant=with_overrides(cfg, {"m1": 1100.0}))
    np.testing.assert_array_equal(_twists(out, "/dcsms/velocity/stage1")[:, 2],
                                  res.velocity[:, 1, 0])


def test_existing_out_refused(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An existing OUT is never overwritten: exit 2 before simulating."""
    assert main(["sim", "--duration", "1", "--out", str(bag)]) == 2
    assert "exists already" in capsys.readouterr().err


def test_parse_schedule() -> None:
    """T:MODE items in any order, any mode spelling."""
    assert parse_schedule("20:DFBC+FFC, 5:fbc") == [(5.0, Mode.FBC), (20.0, Mode.DFBC_FFC)]
    assert parse_schedule("") == []


def test_sim_prints_the_supervisors_transitions_and_no_supervisor_latches(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A floor bag with a burst (x300 from 0.5 to 1.2 s): the supervisor rides through in FBC
    and comes back to DFBC+FFC, each transition printed; ``--no-supervisor`` rides nothing
    and, the burst being below the trip, stays in DFBC+FFC without a transition."""
    cfg = load_config(Path(__file__).resolve().parents[2] / "config" / "table1.yaml")
    ground = simulate(cfg, Mode.PASSIVE, 4.0, seed=5, trip=False).truth[:, 0].copy()
    ground[1000:2400] *= 300.0
    floor = tmp_path / "floor"
    write_result_bag(simulate(cfg, Mode.PASSIVE, 4.0, ground=ground, trip=False), floor)
    quick = ["--set", "supervisor.recover_after_s=0.5", "--set", "supervisor.settle_s=0.3"]
    assert main(["sim", "--mode", "dfbc_ffc", "--duration", "3.5", "--ground-from", str(floor),
                 "--out", str(tmp_path / "on"), *quick]) == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.startswith("dcsms: supervisor: ")]
    assert [x.split()[2:4] for x in lines] == [["RIDE_THROUGH", "FBC"],
                                               ["RECOVERING", "DFBC+FFC"],
                                               ["ENGAGED", "DFBC+FFC"]], err
    assert main(["sim", "--mode", "dfbc_ffc", "--duration", "3.5", "--ground-from", str(floor),
                 "--out", str(tmp_path / "off"), "--no-supervisor", *quick]) == 0
    assert "dcsms: supervisor:" not in capsys.readouterr().err
