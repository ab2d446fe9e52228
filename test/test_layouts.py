"""The PlotJuggler and Foxglove layouts name real /dcsms topics and real message fields."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from dcsms_ros import cdr
from dcsms_ros.cli.common import default_config_path
from dcsms_ros.core import topics
from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import controller_ids
from dcsms_ros.core.simulator import PlantSimulator

LAYOUTS = Path(__file__).resolve().parents[1] / "layouts"
CFG = load_config(default_config_path())
N = CFG.plant.num_stages
#: every topic of the 2-stage graph and its type
TYPES = {topics.velocity_topic(b): cdr.TWIST_STAMPED for b in topics.body_names(N)}
TYPES |= {topics.truth_topic(b): cdr.TWIST_STAMPED for b in topics.body_names(N)}
TYPES |= {topics.force_topic(c): cdr.WRENCH_STAMPED for c in (*controller_ids(N),
                                                               topics.EXCITATION_ID)}
TYPES |= {topics.ACTUATORS_APPLIED: cdr.JOINT_STATE, topics.MODE: cdr.STRING,
          topics.DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray"}
ACTUATORS = PlantSimulator(CFG, seed=0, disturbances=False).actuator_names


def _field_type(msgtype: str, path: list[str]) -> str:
    """Type of a nested field (``twist``, ``linear``, ``z``), or KeyError."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    for name in path:
        fields = dict(ts.get_msgdef(msgtype).fields)
        kind = fields[name]  # KeyError: no such field
        node = kind[1] if kind[0].name in ("NAME", "BASE") else kind[1][0]
        msgtype = node if isinstance(node, str) else node[0]
    return msgtype


def _split(series: str) -> tuple[str, list[str]]:
    """The longest known topic that prefixes ``series`` and the rest of the path."""
    topic = max((t for t in TYPES if series.startswith((t + "/", t + "."))), key=len)
    return topic, re.split(r"[/.]", series[len(topic) + 1:])


def test_plotjuggler_curves_are_real_fields() -> None:
    root = ET.parse(LAYOUTS / "dcsms.plotjuggler.xml").getroot()
    curves = [c.get("name") for c in root.iter("curve")]
    assert len(curves) >= 12
    for name in curves:
        topic, path = _split(name)
        if TYPES[topic] == cdr.JOINT_STATE:  # PlotJuggler: <topic>/<joint name>/<field>
            joint = "/".join(path[:-1])
            assert joint in ACTUATORS and path[-1] == "effort", name
            continue
        assert _field_type(TYPES[topic], path) == "float64", name
    assert {_split(c)[0] for c in curves} >= {topics.velocity_topic("stage2"),
                                              topics.EXCITATION, topics.ACTUATORS_APPLIED}


def test_foxglove_paths_are_real_fields() -> None:
    doc = json.loads((LAYOUTS / "dcsms.foxglove.json").read_text())
    panels = doc["configById"]
    used = set()

    def leaves(node: object) -> list[str]:
        if isinstance(node, str):
            return [node]
        assert isinstance(node, dict)
        return leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(doc["layout"])) == sorted(panels)  # every panel is placed
    for pid, cfg in panels.items():
        if pid.startswith("DiagnosticSummary"):
            assert cfg["topicToRender"] == topics.DIAGNOSTICS
            continue
        for p in cfg["paths"]:
            topic, path = _split(p["value"])
            used.add(topic)
            m = re.fullmatch(r"(\w+)\[(\d+)\]", path[-1])
            if m:
                assert int(m.group(2)) < len(ACTUATORS) and m.group(1) == "effort"
                continue
            want = "string" if TYPES[topic] == cdr.STRING else "float64"
            assert _field_type(TYPES[topic], path) == want, p["value"]
    assert {topics.MODE, topics.EXCITATION, topics.velocity_topic("ground")} <= used


@pytest.mark.parametrize("name", ["dcsms.plotjuggler.xml", "dcsms.foxglove.json"])
def test_layouts_are_installed(name: str) -> None:
    """setup.py installs layouts/ into share/dcsms_ros/layouts."""
    setup = (LAYOUTS.parent / "setup.py").read_text()
    assert '"/layouts", sorted(glob("layouts/*"))' in setup
    assert (LAYOUTS / name).is_file()
