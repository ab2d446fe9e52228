"""The shipped parameter presets: they load, say what they assume, and have sane geometry."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from dcsms_ros.analysis.predict import predict_table4
from dcsms_ros.core import analytics as an
from dcsms_ros.core.config import load_config
from dcsms_ros.core.geometry import MAX_CONDITION, condition, drive_matrix, sensor_matrix
from dcsms_ros.core.model import plant_state_space
from dcsms_ros.core.modes import ALL_MODES
from dcsms_ros.errors import ConfigError

CONFIG = Path(__file__).resolve().parents[2] / "config"
PRESETS = ["table1.yaml", "prototype.yaml", "tem_three_point.yaml", "tem_paper_fit.yaml",
           "tem_paper_fit_v2.yaml"]
#: The presets fitted to the paper's Table 4; their headers quote the model's prediction.
FITS = ["tem_paper_fit.yaml", "tem_paper_fit_v2.yaml"]


@pytest.mark.parametrize("name", PRESETS)
def test_preset_loads_and_is_stable_in_every_mode(name):
    """Each preset loads and its closed loop is stable in all six modes."""
    cfg = load_config(CONFIG / name)
    assert cfg.source.endswith(name)
    assert all(an.is_stable(cfg, m) for m in ALL_MODES)


@pytest.mark.slow
@pytest.mark.parametrize("name", FITS)
def test_fit_header_quotes_the_model(name):
    """A fit's header quotes ``model table4`` (FBC / FBC+FFC / DFBC / DFBC+FFC per axis) to its
    three digits: the numbers a reader compares with the paper are the preset's own."""
    text = (CONFIG / name).read_text()
    pred = predict_table4(load_config(CONFIG / name)).values
    for axis in "xyz":
        m = re.search(rf"^#\s+{axis.upper()} ([0-9.]+) / ([0-9.]+) / ([0-9.]+) / ([0-9.]+)\s+paper",
                      text, re.MULTILINE)
        assert m is not None, f"{name}: no predicted {axis.upper()} row in the header"
        model = [pred[r][axis] for r in ("FBC", "FBC+FFC", "DFBC", "DFBC+FFC")]
        np.testing.assert_allclose([float(v) for v in m.groups()], model, atol=6e-4)


@pytest.mark.parametrize("name", ["prototype.yaml", "tem_three_point.yaml",
                                  "tem_paper_fit_v2.yaml"])
def test_every_preset_value_has_a_unit_comment(name):
    """Every scalar or list value line of the new presets carries a comment (its unit)."""
    lines = (CONFIG / name).read_text().splitlines()
    for i, line in enumerate(lines):
        body = line.split("#", 1)[0]
        if re.match(r"^\s+[a-z_]+:\s*\S", body):
            j = i  # a flow list may close (with its comment) a few lines down
            while body.count("[") > body.count("]"):
                j += 1
                body += lines[j].split("#", 1)[0]
            assert "#" in lines[j], line


def test_prototype_table3_values():
    """Prototype: m1 = 700 + 4 x 27 kg, k1 = 4 x 310 N/mm, m2 = 750 kg."""
    cfg = load_config(CONFIG / "prototype.yaml")
    s1, s2 = cfg.plant.stages
    np.testing.assert_allclose([s1.mass, s1.stiffness, s2.mass], [808.0, 1.24e6, 750.0])
    np.testing.assert_allclose(s1.mass + s2.mass, 1558.0)  # what the steel springs carry


def test_prototype_air_spring_frequency_is_the_stated_assumption():
    """sqrt(k2/m2)/2pi equals the frequency its stiffness comment states."""
    text = (CONFIG / "prototype.yaml").read_text()
    stated = float(re.search(r"assumed air-spring frequency ([0-9.]+) Hz", text).group(1))
    cfg = load_config(CONFIG / "prototype.yaml")
    np.testing.assert_allclose(an.uncoupled_frequencies(cfg)[1], stated, rtol=1e-4)
    assert 1.5 <= stated <= 3.0


def test_prototype_damping_ratios_are_the_stated_ones():
    """c1 and c2 give the 2 % and 5 % damping ratios the header states."""
    cfg = load_config(CONFIG / "prototype.yaml")
    zeta = [s.damping / (2 * math.sqrt(s.stiffness * s.mass)) for s in cfg.plant.stages]
    np.testing.assert_allclose(zeta, [0.02, 0.05], rtol=1e-3)


def test_tem_three_point_geometry_full_rank():
    """TEM preset: >= 6 geophones per body and >= 6 actuators per stage, rank 6, well
    conditioned; three air mounts under the TEM, four springs under the block."""
    cfg = load_config(CONFIG / "tem_three_point.yaml")
    bodies = [(cfg.plant.ground_sensors, np.zeros(3))]
    bodies += [(s.sensors, np.asarray(s.com)) for s in cfg.plant.stages]
    for sens, ref in bodies:
        s = sensor_matrix(np.array(sens.position), np.array(sens.direction), ref)
        assert s.shape[0] >= 6 and np.linalg.matrix_rank(s) == 6
        assert condition(s) < 10.0 < MAX_CONDITION
    for st in cfg.plant.stages:
        b = drive_matrix(np.array(st.actuators.position), np.array(st.actuators.direction),
                         np.asarray(st.com))
        assert b.shape[1] >= 6 and np.linalg.matrix_rank(b) == 6 and condition(b) < 10.0
    assert [len(s.mounts.position) for s in cfg.plant.stages] == [4, 3]
    assert np.all(np.linalg.eigvals(plant_state_space(cfg).a).real < 0)


def test_tem_three_point_vertical_frequencies():
    """TEM preset: air mounts tuned to 2.0 Hz with the TEM, springs to 4.0 Hz with everything."""
    cfg = load_config(CONFIG / "tem_three_point.yaml")
    s1, s2 = cfg.plant.stages
    np.testing.assert_allclose(math.sqrt(s2.stiffness / s2.mass) / (2 * math.pi), 2.0, rtol=1e-4)
    np.testing.assert_allclose(math.sqrt(s1.stiffness / (s1.mass + s2.mass)) / (2 * math.pi),
                               4.0, rtol=1e-4)


def _tem_doc() -> dict:
    return yaml.safe_load((CONFIG / "tem_three_point.yaml").read_text())


def test_singular_sensor_geometry_fails_naming_field_and_file(tmp_path):
    """All TEM geophones vertical: the sensor matrix has rank 3; ConfigError names both."""
    doc = _tem_doc()
    sens = doc["/**"]["ros__parameters"]["stage2"]["sensors"]
    sens["direction"] = [0.0, 0.0, 1.0] * 6
    path = tmp_path / "bad_sensors.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=r"bad_sensors\.yaml.*stage2\.sensors"):
        load_config(path)


def test_singular_mount_geometry_fails_naming_field_and_file(tmp_path):
    """Air mounts with no lateral stiffness cannot hold the TEM: ConfigError names both."""
    doc = _tem_doc()
    mounts = doc["/**"]["ros__parameters"]["stage2"]["mounts"]
    mounts["stiffness"] = [0.0, 0.0, 78957.0] * 3
    path = tmp_path / "bad_mounts.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=r"bad_mounts\.yaml.*stage2\.mounts"):
        load_config(path)
