"""Config validation: bad values and keys fail with the field and the file named."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from dcsms_ros.core.config import config_from_flat, load_config
from dcsms_ros.errors import ConfigError

CONFIG = Path(__file__).resolve().parents[2] / "config"


def _write(tmp_path: Path, params: dict) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


@pytest.mark.parametrize("params,field", [
    ({"stage1": {"mass": 0.0}}, "stage1.mass"),
    ({"stage2": {"mass": -5.0}}, "stage2.mass"),
    ({"stage1": {"stiffness": float("nan")}}, "stage1.stiffness"),
    ({"stage2": {"damping": float("inf")}}, "stage2.damping"),
    ({"stage1": {"damping": -1.0}}, "stage1.damping"),
    ({"stage1": {"mas": 900.0}}, "stage1.mas"),
    ({"plant": {"rate_hz": "fast"}}, "plant.rate_hz"),
    ({"feedback": {"stage1": {"gain": [1.0, 2.0]}}}, "feedback.stage1.gain"),
])
def test_bad_value_names_field_and_file(tmp_path, params, field):
    """Zero/negative mass, NaN/Inf, unknown key, wrong type or length: field and file named."""
    path = _write(tmp_path, params)
    with pytest.raises(ConfigError, match=r"bad\.yaml.*" + re.escape(field)):
        load_config(path)


def test_unknown_key_suggests_the_close_name():
    """A misspelt key names the unknown key and suggests the valid one."""
    with pytest.raises(ConfigError, match=r"'stage1\.mas'.*did you mean 'stage1\.mass'"):
        config_from_flat({"stage1.mas": 1.0}, "x.yaml")


def test_6dof_key_in_1dof_file_is_rejected():
    """A 6dof-only key (mounts) in a 1dof config is an error naming the key."""
    with pytest.raises(ConfigError, match=r"stage1\.mounts\.position"):
        config_from_flat({"stage1.mounts.position": [0.0, 0.0, 0.0]}, "x.yaml")


def test_table1_defaults_in_si():
    """Table 1 loads with the SI values of NOTES.md."""
    cfg = load_config(CONFIG / "table1.yaml")
    s1, s2 = cfg.plant.stages
    assert (s1.mass, s2.mass, s1.stiffness, s1.damping) == (988.8, 748.8, 1.2e6, 1960.0)
