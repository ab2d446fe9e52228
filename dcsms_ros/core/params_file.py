"""ROS 2 params files as text: read, merge and flatten ``<node>: ros__parameters`` blocks into
``{dotted.name: value}`` (as ROS 2 does), and write flat parameters back as a params file."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from dcsms_ros.errors import ConfigError


def read_params_file(path: str | Path) -> dict[str, Any]:
    """Read a ROS 2 params YAML file and return its merged, flattened ``{dotted: value}``."""
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    return parse_params_text(text, str(p))


def parse_params_text(text: str, source: str) -> dict[str, Any]:
    """Merge and flatten the ``<node>: ros__parameters: {...}`` blocks of params-file text."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" line {where.line + 1}" if where is not None else ""
        raise ConfigError(f"{source}:{line} invalid YAML: {getattr(exc, 'problem', exc)}") \
            from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{source}: expected '<node>: ros__parameters: {{...}}' at the top "
                          "level")
    flat: dict[str, Any] = {}
    for node, block in doc.items():
        if not isinstance(block, dict) or "ros__parameters" not in block:
            raise ConfigError(f"{source}: '{node}' has no 'ros__parameters' block")
        params = block["ros__parameters"]
        if not isinstance(params, dict):
            raise ConfigError(f"{source}: '{node}.ros__parameters' must be a mapping")
        _flatten(params, "", flat)
    return flat


def params_text(flat: Mapping[str, Any]) -> str:
    """Flat parameters as a ROS 2 params file, ``/**: ros__parameters: {dotted: value}``: the
    form of ``/dcsms/config``, so a recorded configuration can be passed back with
    ``--params-file`` or ``--config``."""
    return yaml.safe_dump({"/**": {"ros__parameters": dict(sorted(flat.items()))}},
                          sort_keys=False, default_flow_style=None)


def _flatten(d: Mapping[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            _flatten(v, name + ".", out)
        else:
            out[name] = v
