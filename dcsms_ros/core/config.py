"""The configuration loaded from ROS 2 parameter YAML files (the dataclasses of
:mod:`.configtypes`, re-exported here).

A file holds ``<node or /**>: ros__parameters: {...}`` blocks; every block is merged, nested keys
become dotted names (as ROS 2 does), and each name is checked against :mod:`.schema`. Errors name
the field and the file. The nodes receive the same dataclasses, so the numeric core never sees
ROS types.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dcsms_ros.core import configtypes
from dcsms_ros.core.configtypes import (
    ActuatorConfig,
    ControlConfig,
    DisturbanceConfig,
    FeedbackConfig,
    FeedforwardConfig,
    Mounts,
    PlantConfig,
    SensorConfig,
    StageConfig,
    SupervisorConfig,
    SystemConfig,
    Transducers,
)
from dcsms_ros.core.geometry import (
    check_full_rank,
    check_stiffness,
    drive_matrix,
    mount_matrices,
    sensor_matrix,
)
from dcsms_ros.core.params_file import params_text, parse_params_text, read_params_file
from dcsms_ros.core.schema import (
    check_value,
    expand_specs,
    resolve_alias,
    stage_name,
    suggest,
)
from dcsms_ros.errors import ConfigError, GeometryError

# ---------------------------------------------------------------------------------------------
# Loading


def parse_override(text: str) -> tuple[str, Any]:
    """Parse one ``--set NAME=VALUE``; VALUE is YAML (``1.5e6``, ``[1, 2, 3]``, ``true``)."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected NAME=VALUE")
    name, _, raw = text.partition("=")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        raise ConfigError(f"--set {name}: cannot parse value {raw!r}") from None
    return resolve_alias(name.strip()), value


def load_config(path: str | Path | None = None,
                overrides: Mapping[str, Any] | None = None) -> SystemConfig:
    """Load a params file (or the built-in defaults when ``path`` is None) and apply overrides.

    Parameters
    ----------
    path : str or Path, optional
        ROS 2 params YAML file, e.g. ``config/table1.yaml``.
    overrides : mapping, optional
        Dotted names (or aliases such as ``c1``) to values; applied after the file.
    """
    flat = read_params_file(path) if path is not None else {}
    source = str(path) if path is not None else "<defaults>"
    for name, value in (overrides or {}).items():
        flat[resolve_alias(name)] = value
    return config_from_flat(flat, source)


def config_from_flat(flat: Mapping[str, Any], source: str = "<params>") -> SystemConfig:
    """Validate a flat ``{dotted: value}`` mapping and build a :class:`SystemConfig`.

    Raises
    ------
    ConfigError
        Naming the field and ``source`` for an unknown key, a wrong type or length, a value out
        of range, NaN/Inf, or an inconsistent 6-DOF geometry.
    """
    fidelity = flat.get("plant.fidelity", "1dof")
    n_raw = flat.get("plant.num_stages", 2)
    if isinstance(n_raw, bool) or not isinstance(n_raw, int) or not 1 <= n_raw <= 8:
        raise ConfigError(f"{source}: plant.num_stages must be an integer in [1, 8], got {n_raw!r}")
    specs = expand_specs(n_raw)
    values: dict[str, Any] = {}
    for name, raw in flat.items():
        spec = specs.get(name)
        if spec is None:
            raise ConfigError(f"{source}: unknown parameter '{name}'" + suggest(name, specs))
        if spec.fidelity and spec.fidelity != fidelity:
            raise ConfigError(f"{source}: '{name}' applies to fidelity {spec.fidelity}, but "
                              f"plant.fidelity is {fidelity}")
        values[name] = check_value(spec, raw, source)
    for name, spec in specs.items():
        if name not in values and (not spec.fidelity or spec.fidelity == fidelity):
            default = spec.default
            values[name] = list(default) if isinstance(default, list) else default
    return _build(values, source)


def _triples(values: list[float]) -> tuple[tuple[float, float, float], ...]:
    return tuple((values[i], values[i + 1], values[i + 2]) for i in range(0, len(values), 3))


def _unit(v: tuple[float, float, float], where: str) -> tuple[float, float, float]:
    n = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    if n == 0.0:
        raise ConfigError(f"{where}: a direction is the zero vector")
    return (v[0] / n, v[1] / n, v[2] / n)


def _transducers(values: Mapping[str, Any], prefix: str, source: str) -> Transducers:
    pos = _triples(values[f"{prefix}.position"])
    dirs = _triples(values[f"{prefix}.direction"])
    if len(pos) != len(dirs):
        raise ConfigError(f"{source}: {prefix}: {len(pos)} positions but {len(dirs)} directions")
    return Transducers(pos, tuple(_unit(d, f"{source}: {prefix}.direction") for d in dirs))


def _build(v: Mapping[str, Any], source: str) -> SystemConfig:
    fidelity = v["plant.fidelity"]
    n = v["plant.num_stages"]
    stages = []
    for i in range(1, n + 1):
        s = stage_name(i)
        if fidelity == "1dof":
            stages.append(StageConfig(s, v[f"{s}.mass"], v[f"{s}.stiffness"], v[f"{s}.damping"],
                                      v[f"{s}.actuators.count"]))
            continue
        mp = _triples(v[f"{s}.mounts.position"])
        mk = _triples(v[f"{s}.mounts.stiffness"])
        mc = _triples(v[f"{s}.mounts.damping"])
        if not mp:
            raise ConfigError(f"{source}: {s}.mounts.position: a 6dof stage needs mounts")
        if not len(mp) == len(mk) == len(mc):
            raise ConfigError(f"{source}: {s}.mounts: {len(mp)} positions, {len(mk)} stiffness "
                              f"and {len(mc)} damping triples must agree")
        acts = _transducers(v, f"{s}.actuators", source)
        if not acts.position:
            raise ConfigError(f"{source}: {s}.actuators.position: a 6dof stage needs actuators")
        stages.append(StageConfig(
            s, v[f"{s}.mass"], sum(k[2] for k in mk), sum(c[2] for c in mc),
            len(acts.position), tuple(v[f"{s}.inertia"]), tuple(v[f"{s}.com"]),
            Mounts(mp, mk, mc), _transducers(v, f"{s}.sensors", source), acts))
    ground = (_transducers(v, "ground.sensors", source) if fidelity == "6dof" else Transducers())
    plant = PlantConfig(fidelity, v["plant.rate_hz"], tuple(stages), ground)
    feedback = tuple(
        FeedbackConfig(tuple(v[f"feedback.{s.name}.gain"]),
                       **{k: v[f"feedback.{s.name}.{k}"] for k in
                          ("highpass_hz", "highpass_order", "lowpass_hz", "lowpass_order",
                           "notch_hz", "notch_q", "lead_hz", "lag_hz")})
        for s in stages)
    cfg = SystemConfig(
        plant=plant,
        sensors=SensorConfig(**_section(v, "sensors")),
        actuators=ActuatorConfig(**_section(v, "actuators")),
        feedback=feedback,
        feedforward=FeedforwardConfig(**_section(v, "feedforward")),
        control=ControlConfig(**_section(v, "control")),
        disturbance=DisturbanceConfig(**_section(v, "disturbance")),
        supervisor=SupervisorConfig(**_section(v, "supervisor")),
        source=source,
        params=dict(v),
    )
    if fidelity == "6dof":
        check_geometry(cfg)
    return cfg


def check_geometry(cfg: SystemConfig) -> None:
    """Check every sensor, drive and mount layout of a 6-DOF config (full rank, sane condition
    number, non-singular suspension); the :class:`ConfigError` names the field and the file."""
    bodies = [("ground", cfg.plant.ground_sensors, np.zeros(3))]
    bodies += [(s.name, s.sensors, np.asarray(s.com)) for s in cfg.plant.stages]
    try:
        for name, sens, ref in bodies:
            s = sensor_matrix(np.array(sens.position), np.array(sens.direction), ref)
            check_full_rank(s, f"{name}.sensors (sensor matrix)")
        for st in cfg.plant.stages:
            b = drive_matrix(np.array(st.actuators.position), np.array(st.actuators.direction),
                             np.asarray(st.com))
            check_full_rank(b, f"{st.name}.actuators (drive matrix)")
        for st in cfg.plant.stages:
            k, _ = mount_matrices(np.array(st.mounts.position), np.array(st.mounts.stiffness),
                                  np.array(st.mounts.damping))
            check_stiffness(k, f"{st.name}.mounts")
    except GeometryError as exc:
        raise ConfigError(f"{cfg.source}: {exc}") from None


def _section(v: Mapping[str, Any], prefix: str) -> dict[str, Any]:
    out = {}
    for name, value in v.items():
        head, _, rest = name.partition(".")
        if head == prefix and "." not in rest:
            out[rest] = tuple(value) if isinstance(value, list) else value
    return out


def with_overrides(cfg: SystemConfig, overrides: Mapping[str, Any]) -> SystemConfig:
    """A new config with dotted-name (or alias) overrides applied and validated again."""
    flat = dict(cfg.params or {})
    for name, value in overrides.items():
        flat[resolve_alias(name)] = value
    return config_from_flat(flat, cfg.source)


def scaled(cfg: SystemConfig, param: str, factor: float) -> SystemConfig:
    """A new config with one of m1, m2, c1, c2, k1, k2 (any stage) multiplied by ``factor``.

    In 6dof, ``k``/``c`` scale every mount of that stage on every axis.
    """
    name = resolve_alias(param)
    flat = dict(cfg.params or {})
    if cfg.plant.fidelity == "6dof" and name.endswith((".stiffness", ".damping")):
        stage, _, what = name.partition(".")
        key = f"{stage}.mounts.{what}"
        flat[key] = [x * factor for x in flat[key]]
    elif name in flat and isinstance(flat[name], (int, float)):
        flat[name] = flat[name] * factor
    else:
        raise ConfigError(f"{cfg.source}: cannot scale '{param}': not a numeric parameter")
    return config_from_flat(flat, cfg.source)


__all__ = ["check_geometry", "config_from_flat", "load_config", "params_text", "parse_override",
           "parse_params_text", "read_params_file", "replace", "scaled", "with_overrides"]
# the dataclasses, re-exported (``from dcsms_ros.core.config import SystemConfig``)
__all__ += configtypes.__all__
