"""launch/dcsms.launch.py compiles and enables the same controllers per mode as the core."""

from __future__ import annotations

import ast
import py_compile
from pathlib import Path

from dcsms_ros.core.modes import Mode, enabled_controllers

LAUNCH = Path(__file__).resolve().parents[2] / "launch" / "dcsms.launch.py"


def test_launch_file_compiles_and_matches_the_mode_table():
    """The launch file is valid Python and its ENABLED table equals core.modes (2 stages)."""
    py_compile.compile(str(LAUNCH), doraise=True)
    tree = ast.parse(LAUNCH.read_text())
    table = next(ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
                 and getattr(n.targets[0], "id", "") == "ENABLED")
    assert {m: set(v) for m, v in table.items()} == {
        m.value: set(enabled_controllers(m, 2)) for m in Mode}
