"""`dcsms demo`: the main job end to end (batch engine here; the graph runs in `make demo`)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from dcsms_ros.analysis.predict import predict_table4
from dcsms_ros.cli import demo, main
from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import ALL_MODES

TABLE1 = Path(__file__).resolve().parents[2] / "config" / "table1.yaml"
TEM = TABLE1.parent / "tem_paper_fit.yaml"


@pytest.mark.slow
def test_batch_demo_reproduces_the_paper_ordering(tmp_path, capsys):
    """Six modes, recorded and analysed: Z ordering as Table 4, DFBC+FFC <= 0.1, no saturation."""
    out = tmp_path / "demo"
    assert main(["demo", "--engine", "batch", "--config", str(TABLE1), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Passive > FBC > FBC+FFC > DFBC > DFBC+FFC: reproduced" in text
    summary = json.loads((out / "summary.json").read_text())
    z = {s["mode"]: s["axes"]["z"]["normalized"] for s in summary["segments"]}
    assert list(z) == ["Passive", "FBC", "FFC", "FBC+FFC", "DFBC", "DFBC+FFC"]
    assert z["Passive"] > z["FBC"] > z["FBC+FFC"] > z["DFBC"] > z["DFBC+FFC"]
    assert z["DFBC+FFC"] <= 0.1
    for seg in summary["segments"]:
        for f in seg["forces"]:
            assert f["peak_n"] <= f["limit_n"] and f["saturated_samples"] == 0
    assert (out / "report.md").read_text().startswith("# DCSMS vibration analysis")
    assert (out / "transmissibility_z.png").stat().st_size > 10_000


def test_demo_refuses_to_replace_a_foreign_directory(tmp_path, capsys):
    """An --out directory that an earlier demo did not write is left alone: exit 2, one line."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main(["demo", "--engine", "batch", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not overwriting" in err[0]
    assert (out / "notes.txt").read_text() == "keep me"


def test_demo_that_cannot_create_its_output_says_so_in_one_line(tmp_path, capsys):
    """An --out below a regular file: exit 2 and one line, before anything runs."""
    (tmp_path / "file").write_text("keep me")
    out = tmp_path / "file" / "demo"
    assert main(["demo", "--engine", "batch", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot create" in err[0] and str(out) in err[0], err
    assert (tmp_path / "file").read_text() == "keep me"


@pytest.mark.slow
def test_demo_with_a_mode_subset_is_judged_on_the_modes_it_ran(tmp_path, capsys):
    """--modes Passive,DFBC+FFC: exit 0, the ordering of those two, the skipped ones named.
    20 s per mode: with 7 s the value's 95 % interval spans 0.07-0.30 around the 0.1 bar."""
    out = tmp_path / "sub"
    assert main(["demo", "--engine", "batch", "--config", str(TABLE1), "--modes",
                 "Passive,DFBC+FFC", "--segment", "20", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Passive > DFBC+FFC: reproduced (not run: FBC, FBC+FFC, DFBC)" in text


@pytest.mark.slow
def test_default_demo_is_the_papers_tem_experiment(tmp_path, capsys):
    """No --config: the three-point TEM in X / Y / Z, 60 s per mode with the batch engine. Every
    axis keeps the paper's order, nothing saturates, and each normalised value lies within
    50 % of the loop model's prediction for a long run (60 s segments scatter ~15 %)."""
    out = tmp_path / "tem"
    assert main(["demo", "--engine", "batch", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for axis in "XYZ":
        assert f"order in {axis} " in text and "NOT reproduced" not in text
    summary = json.loads((out / "summary.json").read_text())
    assert f"config {TEM}" in text
    cfg = load_config(TEM)
    model = predict_table4(cfg, ALL_MODES).values
    for seg in summary["segments"]:
        assert seg["duration_s"] >= 59.0
        for f in seg["forces"]:
            assert f["saturated_samples"] == 0
        for axis in "xyz":
            ours = seg["axes"][axis]["normalized"]
            assert abs(ours / model[seg["mode"]][axis] - 1.0) < 0.5, (seg["mode"], axis, ours)


def _summary_from(values, spread=1.3):
    """A demo summary holding normalised X / Y / Z values per mode label, each with the
    interval [value / spread, value * spread]."""
    segs = [{"mode": m, "axes": {a: {"normalized": v[i], "normalized_ci": [v[i] / spread,
                                                                           v[i] * spread]}
                                 for i, a in enumerate("xyz")},
             "forces": [], "stability": {}} for m, v in values.items()]
    return SimpleNamespace(segments=segs, axes=["x", "y", "z"], paper=None)


@pytest.mark.slow
def test_order_verdict_tolerates_only_swaps_the_record_cannot_resolve(capsys):
    """A swap of X's DFBC and DFBC+FFC (model 1.3x apart, intervals +-30 %: overlapping) is
    named and passes, and so are those neighbours kept in order but overlapping; a swap of Z's
    FBC and DFBC+FFC (model 14x apart: disjoint intervals) fails the verdict, and so does the
    close swap without intervals."""
    model = predict_table4(load_config(TEM), ALL_MODES)
    base = {m: [model.values[m][a] for a in "xyz"] for m in demo.ORDER}
    close = {m: list(v) for m, v in base.items()}
    close["DFBC"][0], close["DFBC+FFC"][0] = base["DFBC+FFC"][0], base["DFBC"][0]
    assert demo._verdict_3d(_summary_from(close), model)
    assert "reproduced within the 95 % intervals" in capsys.readouterr().out
    # the model's own values, +-30 %: X's DFBC and DFBC+FFC kept in order but overlapping
    assert demo._verdict_3d(_summary_from(base), model)
    out = capsys.readouterr().out
    assert ("order in X FBC > FBC+FFC > DFBC > DFBC+FFC (paper's): reproduced; not resolved by "
            "the record (95 % intervals overlap): FBC / FBC+FFC, DFBC / DFBC+FFC") in out, out
    assert demo._verdict_3d(_summary_from(base, spread=1.0), model)
    assert "not resolved" not in capsys.readouterr().out
    assert not demo._verdict_3d(_summary_from(close, spread=1.0), model)
    assert "NOT reproduced" in capsys.readouterr().out
    far = {m: list(v) for m, v in base.items()}
    far["FBC"][2], far["DFBC+FFC"][2] = base["DFBC+FFC"][2], base["FBC"][2]
    assert not demo._verdict_3d(_summary_from(far), model)
    assert "order in Z FBC > FBC+FFC > DFBC > DFBC+FFC (paper's): NOT reproduced" in \
        capsys.readouterr().out
