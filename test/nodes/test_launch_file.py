"""launch/dcsms.launch.py builds its nodes from dcsms_ros.graph.define_graph (no fixed stage
count, no copy of the mode table), run here against stand-ins of the launch packages (not
installable here) to see the nodes it would start."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path
from typing import Any

import pytest
import yaml

from dcsms_ros.core.config import load_config
from dcsms_ros.graph import define_graph

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / "launch" / "dcsms.launch.py"


class _Action:
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


@pytest.fixture
def launch_module(monkeypatch: pytest.MonkeyPatch) -> Any:
    """The launch file imported with minimal stand-ins for launch, launch_ros and ament."""
    values: dict[str, str] = {}

    class LaunchConfiguration:
        def __init__(self, name: str) -> None:
            self.name = name

        def perform(self, context: Any) -> str:
            return values[self.name]

    fake = {
        "launch": types.SimpleNamespace(LaunchDescription=list),
        "launch.actions": types.SimpleNamespace(DeclareLaunchArgument=_Action,
                                                ExecuteProcess=_Action, OpaqueFunction=_Action),
        "launch.substitutions": types.SimpleNamespace(LaunchConfiguration=LaunchConfiguration),
        "launch_ros": types.SimpleNamespace(),
        "launch_ros.actions": types.SimpleNamespace(Node=_Action),
        "ament_index_python": types.SimpleNamespace(),
        "ament_index_python.packages": types.SimpleNamespace(
            get_package_share_directory=lambda pkg: str(REPO)),
    }
    for name, mod in fake.items():
        monkeypatch.setitem(sys.modules, name, mod)
    spec = importlib.util.spec_from_file_location("dcsms_launch", LAUNCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.values = values  # type: ignore[attr-defined]
    return module


def _run(module: Any, **args: str) -> list[_Action]:
    defaults = {a.args[0]: a.kwargs["default_value"]
                for a in module.generate_launch_description() if a.args and
                isinstance(a.args[0], str)}
    module.values.clear()
    module.values.update({**defaults, **args})
    return module._nodes(None)


def test_launch_file_starts_the_graph_definition(launch_module: Any) -> None:
    """Per-process: one Node per NodeSpec, same names, executables, namespace and params."""
    actions = _run(launch_module, mode="dfbc_ffc", namespace="/lab/t2")
    spec = define_graph(load_config(REPO / "config" / "table1.yaml"),
                        mode=__import__("dcsms_ros.core.modes", fromlist=["Mode"]).Mode.DFBC_FFC,
                        namespace="/lab/t2")
    got = [(a.kwargs["name"], a.kwargs["executable"], a.kwargs["namespace"]) for a in actions]
    assert got == [(n.name, n.executable, "/lab/t2") for n in spec.nodes]
    params = yaml.safe_load(Path(actions[0].kwargs["parameters"][0]).read_text())
    assert params == spec.params_document()
    rt = {a.kwargs["name"]: a.kwargs["additional_env"] for a in actions}
    assert rt["mode_switch"] == {}
    assert rt["plant_simulator"] == {"DCSMS_RT_PRIORITY": "0", "DCSMS_RT_CPUS": ""}
    pinned = _run(launch_module, rt_priority="50", rt_cpus="1")
    assert {a.kwargs["name"]: a.kwargs["additional_env"].get("DCSMS_RT_CPUS")
            for a in pinned}["fb_stage1"] == "1"


def test_launch_file_follows_the_number_of_stages(launch_module: Any, tmp_path: Path) -> None:
    """A 3-stage configuration gets fb_stage1..3 (the old launch file fixed 2)."""
    cfg = yaml.safe_load((REPO / "config" / "table1.yaml").read_text())
    block = cfg["/**"]["ros__parameters"]
    block["plant"]["num_stages"] = 3
    block["stage3"] = dict(block["stage2"])
    path = tmp_path / "three.yaml"
    path.write_text(yaml.safe_dump(cfg))
    names = [a.kwargs["name"] for a in _run(launch_module, config=str(path))]
    assert [n for n in names if n.startswith("fb_")] == ["fb_stage1", "fb_stage2", "fb_stage3"]


def test_launch_file_composed_is_one_process(launch_module: Any) -> None:
    """composed:=true: one process running the container with the graph and params files."""
    (proc,) = _run(launch_module, composed="true", schedule="lockstep")
    cmd = proc.kwargs["cmd"]
    assert cmd[1:3] == ["-m", "dcsms_ros.nodes.container"]
    graph = yaml.safe_load(Path(cmd[cmd.index("--graph") + 1]).read_text())
    assert graph["schedule"] == "lockstep" and len(graph["nodes"]) == 6
    assert proc.kwargs["additional_env"] == {"DCSMS_RT_CPUS": ""}
