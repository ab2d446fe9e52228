"""Batch bags with an excitation, shared by the identification, export and analysis tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from true_plant import TRUE_PLANT

from dcsms_ros.cli import main


@pytest.fixture(scope="session")
def excited_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """60 s Passive with 5 N RMS of white noise on stage 1 of the changed plant (CLI)."""
    out = tmp_path_factory.mktemp("excited") / "passive_white"
    argv = ["sim", "--mode", "passive", "--duration", "60", "--seed", "7", "--out", str(out),
            "--excite", "stage1.z:white:5"]
    for name, value in TRUE_PLANT.items():
        argv += ["--plant-set", f"{name}={value}"]
    assert main(argv) == 0
    return out


@pytest.fixture(scope="session")
def closed_loop_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """DFBC+FFC for 20 s then Passive for 20 s, 8 N RMS of white noise on stage 2 for the
    first 30 s, table forces 100 times weaker than the preset's (so the quiet Passive part
    is ground-dominated); plant = configuration."""
    out = tmp_path_factory.mktemp("excited") / "dfbc_ffc_white"
    assert main(["sim", "--mode", "dfbc_ffc", "--duration", "40", "--seed", "8", "--out",
                 str(out), "--schedule", "20:passive", "--excite", "stage2.z:white:8@0-30",
                 "--set", "disturbance.force_rms_n=0.001"]) == 0
    return out
