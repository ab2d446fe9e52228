"""The /dcsms/config text: a ROS 2 params file that round-trips and loads back as --config."""

from __future__ import annotations

from pathlib import Path

import yaml

from dcsms_ros.analysis.reader import config_from_yaml, config_to_yaml
from dcsms_ros.core.config import load_config

CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_config_text_round_trips_as_a_params_file(tmp_path):
    """config_to_yaml -> file -> load_config and -> config_from_yaml give the same system."""
    cfg = load_config(CONFIG / "tem_three_point.yaml", {"feedforward.gain": 0.8})
    text = config_to_yaml(cfg)
    assert list(yaml.safe_load(text)) == ["/**"]
    path = tmp_path / "recorded.yaml"
    path.write_text(text)
    again = load_config(path)
    assert again.params == cfg.params
    assert config_from_yaml(text).params == cfg.params


def test_config_text_of_older_bags_is_still_read():
    """A plain {dotted: value} mapping (bags before the params-file form) still loads."""
    cfg = load_config(CONFIG / "table1.yaml")
    flat = yaml.safe_dump(dict(cfg.params))
    assert config_from_yaml(flat).params == cfg.params
