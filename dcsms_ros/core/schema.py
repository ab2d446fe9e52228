"""The parameter schema: every configurable name, its type, default, SI unit, range and meaning.

One table serves four readers: the YAML loader (validation, unknown keys), the CLI (``--set``
overrides, documentation), the ROS nodes (parameter descriptors with ranges) and the README.
Names are dotted, as ROS 2 flattens nested YAML; ``{s}`` stands for a stage name
(``stage1`` … ``stageN``) and ``{b}`` for a body name (``ground`` or a stage).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from dcsms_ros.errors import ConfigError

INF = math.inf
AXES6 = ("x", "y", "z", "rx", "ry", "rz")


@dataclass(frozen=True)
class ParamSpec:
    """One configurable parameter.

    ``kind`` is ``float``, ``int``, ``bool``, ``str``, ``floats`` (list of float) or ``ints``.
    ``length`` fixes a list's length (0: any, 3k for flattened xyz triples: -3).
    ``fidelity`` is ``""`` (both), ``1dof`` or ``6dof``: a key of the other fidelity is an error.
    """

    name: str
    kind: str
    default: Any
    unit: str
    doc: str
    lo: float = -INF
    hi: float = INF
    length: int = 0
    fidelity: str = ""
    choices: tuple[str, ...] = ()
    lo_open: bool = False  # True: value must be > lo (strictly)


_P = ParamSpec

# Defaults are the paper's Table 1 (1-DOF) and a controller tuned for it; see config/*.yaml.
GLOBAL_SPECS: tuple[ParamSpec, ...] = (
    _P("plant.fidelity", "str", "1dof", "-", "Model fidelity: vertical 1-DOF per stage or "
       "rigid-body 6-DOF per stage", choices=("1dof", "6dof")),
    _P("plant.num_stages", "int", 2, "-", "Number of cascaded stages N (the paper: 2)", 1, 8),
    _P("plant.rate_hz", "float", 2000.0, "Hz", "Control and simulation sample rate", 10.0, 1e5),
    _P("sensors.natural_frequency_hz", "float", 4.5, "Hz", "Geophone natural frequency",
       0.0, 1e3, lo_open=True),
    _P("sensors.damping_ratio", "float", 0.42, "-", "Geophone damping ratio (open circuit)",
       0.0, 10.0, lo_open=True),
    _P("sensors.sensitivity_v_per_mps", "float", 100.4, "V/(m/s)", "Geophone sensitivity",
       0.0, 1e6, lo_open=True),
    _P("sensors.noise_asd", "float", 1e-9, "m/s/sqrt(Hz)", "Geophone self-noise, white, "
       "referred to input velocity above the natural frequency", 0.0, 1.0),
    _P("sensors.dynamics", "bool", True, "-", "Simulate the geophone transfer function "
       "(false: ideal velocity sensors)"),
    _P("sensors.extension_hz", "float", 0.5, "Hz", "Corner of the low-frequency extension "
       "(inverse) filter; 0 disables the extension", 0.0, 1e3),
    _P("sensors.extension_damping", "float", 0.707, "-", "Damping ratio of the extended "
       "response", 0.0, 10.0, lo_open=True),
    _P("actuators.force_limit_n", "float", 100.0, "N", "Peak force of one voice-coil "
       "actuator (saturation)", 0.0, 1e6, lo_open=True),
    _P("feedforward.gain", "float", 0.9, "-", "Scale of the ideal ground feedforward c1 + k1/s "
       "(1: exact cancellation; real sensors and springs leave a mismatch)", 0.0, 10.0),
    _P("feedforward.highpass_hz", "float", 0.5, "Hz", "High-pass corner replacing the pure "
       "integrator of k1/s", 0.0, 1e3, lo_open=True),
    _P("feedforward.highpass_order", "int", 2, "-", "High-pass order", 1, 4),
    _P("feedforward.lowpass_hz", "float", 150.0, "Hz", "Low-pass corner against sensor noise; "
       "0 disables", 0.0, 1e4),
    _P("feedforward.lowpass_order", "int", 2, "-", "Low-pass order", 1, 4),
    _P("control.fade_time_s", "float", 0.5, "s", "Gain fade-in/fade-out time on a mode "
       "switch", 0.0, 60.0),
    _P("control.input_timeout_s", "float", 0.01, "s", "Real time: an input or force older "
       "than this is stale and gives zero force; with a controller's `force_reader` another "
       "node than the plant (a rig), also an input that comes this much later than the "
       "fastest recent delivery", 0.0, 10.0, lo_open=True),
    _P("control.lockstep_timeout_s", "float", 0.5, "s", "Lockstep: wall-clock wait for a "
       "controller's force before it counts as a fault", 0.0, 60.0, lo_open=True),
    _P("control.trip_rms_mps", "float", 1e-3, "m/s", "Instability trip: band-limited RMS of a "
       "table velocity above this latches Passive", 0.0, 10.0, lo_open=True),
    _P("control.trip_band_hz", "floats", [1.0, 200.0], "Hz", "Instability trip pass band "
       "[low, high]", 0.0, 1e4, length=2),
    _P("control.trip_window_s", "float", 0.2, "s", "Instability trip RMS window", 0.0, 60.0,
       lo_open=True),
    _P("supervisor.enabled", "bool", True, "-", "Supervisor (docs/reliability.md): ride "
       "through loud floors, re-engage after a trip; false: any trip latches Passive"),
    _P("supervisor.ride_mode", "str", "fbc", "-", "Calmer mode while the floor is loud "
       "(RIDE_THROUGH)", choices=("passive", "fbc", "ffc", "fbc_ffc", "dfbc", "dfbc_ffc")),
    _P("supervisor.ride_ground_mps", "float", 2e-4, "m/s", "Ground band RMS (trip band and "
       "window) above which the supervisor rides through", 0.0, 10.0, lo_open=True),
    _P("supervisor.ride_force_ratio", "float", 0.8, "-", "Peak actuator force over its limit "
       "above which the supervisor rides through", 0.0, 10.0, lo_open=True),
    _P("supervisor.quiet_fraction", "float", 0.5, "-", "Quiet: ground, force and stage below "
       "this fraction of their thresholds (hysteresis)", 0.0, 1.0, lo_open=True),
    _P("supervisor.recover_after_s", "float", 5.0, "s", "Quiet time before the user's mode is "
       "re-engaged after a ride-through", 0.0, 3600.0),
    _P("supervisor.settle_s", "float", 1.0, "s", "Time RECOVERING lasts before ENGAGED "
       "(fade plus one trip window)", 0.0, 3600.0),
    _P("supervisor.excess_ratio", "float", 4.0, "-", "Stage band RMS over what the loop model "
       "predicts for the measured ground above which a trip is an instability", 1.0, 1e6),
    _P("supervisor.growth_per_s", "float", 2.0, "1/s", "Growth rate of stage over ground band "
       "RMS above which a trip is an instability (modes without a model gain)", 0.0, 1e6,
       lo_open=True),
    _P("supervisor.floor_memory_s", "float", 2.0, "s", "A stage RMS is explained by the "
       "loudest floor of this long ago (ring-down after a burst)", 0.05, 3600.0),
    _P("supervisor.hold_s", "float", 2.0, "s", "Passive hold after the first trip before a "
       "re-engagement", 0.0, 3600.0),
    _P("supervisor.backoff", "float", 2.0, "-", "Hold multiplier per further attempt",
       1.0, 100.0),
    _P("supervisor.max_attempts", "int", 3, "-", "Automatic re-engagements before LATCHED "
       "(only reset_trip clears it)", 0, 100),
    _P("supervisor.attempts_window_s", "float", 120.0, "s", "A clean run this long forgives "
       "the trips before it", 0.0, 1e6),
    _P("disturbance.seed", "int", 1, "-", "Seed of the white-noise disturbances", 0, 2**31 - 1),
    _P("disturbance.ground_rms_mps", "floats", [2e-6, 2e-6, 5e-6], "m/s", "RMS ground "
       "velocity along x, y, z (band-limited white noise)", 0.0, 1.0, length=3),
    _P("disturbance.ground_band_hz", "floats", [0.5, 100.0], "Hz", "Ground noise pass band "
       "[low, high]", 0.0, 1e4, length=2),
    _P("disturbance.force_rms_n", "float", 0.1, "N", "RMS white-noise force on each table "
       "along each translation axis (pumps, fans, chillers)", 0.0, 1e6),
    _P("disturbance.force_band_hz", "floats", [0.5, 100.0], "Hz", "Table force noise pass "
       "band [low, high]", 0.0, 1e4, length=2),
)

BODY_SPECS: tuple[ParamSpec, ...] = (
    _P("{b}.sensors.position", "floats", [], "m", "Geophone positions, x y z per sensor "
       "(flattened), world frame", length=-3, fidelity="6dof"),
    _P("{b}.sensors.direction", "floats", [], "-", "Geophone measuring directions, x y z per "
       "sensor (flattened; normalised on load)", length=-3, fidelity="6dof"),
)

STAGE_SPECS: tuple[ParamSpec, ...] = (
    _P("{s}.mass", "float", 988.8, "kg", "Stage mass", 0.0, 1e7, lo_open=True),
    _P("{s}.stiffness", "float", 1.2e6, "N/m", "Vertical stiffness of the suspension under "
       "the stage (all mounts)", 0.0, 1e12, lo_open=True, fidelity="1dof"),
    _P("{s}.damping", "float", 1960.0, "N*s/m", "Vertical viscous damping of the suspension "
       "under the stage (all mounts)", 0.0, 1e9, fidelity="1dof"),
    _P("{s}.actuators.count", "int", 4, "-", "Vertical actuators under the stage, lumped into "
       "one channel (limit = count x force limit)", 1, 64, fidelity="1dof"),
    _P("{s}.inertia", "floats", [1.0, 1.0, 1.0], "kg*m^2", "Principal moments of inertia "
       "about the centre of mass, Ixx Iyy Izz", 0.0, 1e9, length=3, fidelity="6dof",
       lo_open=True),
    _P("{s}.com", "floats", [0.0, 0.0, 0.0], "m", "Centre of mass in the world frame; also "
       "the stage's reference point for velocities and wrenches", length=3, fidelity="6dof"),
    _P("{s}.mounts.position", "floats", [], "m", "Mount (spring) positions, x y z per mount "
       "(flattened), world frame", length=-3, fidelity="6dof"),
    _P("{s}.mounts.stiffness", "floats", [], "N/m", "Mount stiffness along x y z, per mount "
       "(flattened)", 0.0, 1e12, length=-3, fidelity="6dof"),
    _P("{s}.mounts.damping", "floats", [], "N*s/m", "Mount damping along x y z, per mount "
       "(flattened)", 0.0, 1e9, length=-3, fidelity="6dof"),
    _P("{s}.actuators.position", "floats", [], "m", "Actuator positions, x y z per actuator "
       "(flattened), world frame; each pushes between this stage and the one below",
       length=-3, fidelity="6dof"),
    _P("{s}.actuators.direction", "floats", [], "-", "Actuator force directions, x y z per "
       "actuator (flattened; normalised on load)", length=-3, fidelity="6dof"),
    _P("feedback.{s}.gain", "floats", [0.0, 0.0, 3.0e4, 0.0, 0.0, 0.0], "N*s/m, N*m*s/rad",
       "Velocity-feedback (skyhook) gain per axis x y z rx ry rz; 1dof uses z", 0.0, 1e9,
       length=6),
    _P("feedback.{s}.highpass_hz", "float", 0.3, "Hz", "High-pass corner (drift, offset); 0 "
       "disables", 0.0, 1e3),
    _P("feedback.{s}.highpass_order", "int", 1, "-", "High-pass order", 1, 4),
    _P("feedback.{s}.lowpass_hz", "float", 150.0, "Hz", "Low-pass corner (sensor noise, "
       "structural modes); 0 disables", 0.0, 1e4),
    _P("feedback.{s}.lowpass_order", "int", 2, "-", "Low-pass order", 1, 4),
    _P("feedback.{s}.notch_hz", "float", 0.0, "Hz", "Notch centre; 0 disables", 0.0, 1e4),
    _P("feedback.{s}.notch_q", "float", 5.0, "-", "Notch quality factor", 0.0, 1e3,
       lo_open=True),
    _P("feedback.{s}.lead_hz", "float", 0.0, "Hz", "Lead-lag zero frequency; 0 disables the "
       "lead-lag stage", 0.0, 1e4),
    _P("feedback.{s}.lag_hz", "float", 0.0, "Hz", "Lead-lag pole frequency", 0.0, 1e4),
)

#: Per-stage defaults that differ from the table above (the paper's Table 1 second stage).
STAGE_DEFAULTS: dict[str, Any] = {
    "stage2.mass": 748.8,
    "feedback.stage1.gain": [0.0, 0.0, 1.5e4, 0.0, 0.0, 0.0],
    "feedback.stage2.gain": [0.0, 0.0, 4.5e4, 0.0, 0.0, 0.0],
}

#: Short names accepted by ``--set`` and ``sweep --param``: m1 -> stage1.mass and so on.
ALIASES = {"m": "mass", "k": "stiffness", "c": "damping"}


def stage_name(i: int) -> str:
    """Name of stage ``i`` (1-based)."""
    return f"stage{i}"


def expand_specs(num_stages: int) -> dict[str, ParamSpec]:
    """All parameter specs with ``{s}``/``{b}`` expanded for ``num_stages`` stages."""
    out: dict[str, ParamSpec] = {p.name: p for p in GLOBAL_SPECS}
    stages = [stage_name(i) for i in range(1, num_stages + 1)]
    for b in ["ground", *stages]:
        for p in BODY_SPECS:
            n = p.name.replace("{b}", b)
            out[n] = _renamed(p, n)
    for s in stages:
        for p in STAGE_SPECS:
            n = p.name.replace("{s}", s)
            out[n] = _renamed(p, n, STAGE_DEFAULTS.get(n, p.default))
    return out


def _renamed(p: ParamSpec, name: str, default: Any = None) -> ParamSpec:
    return ParamSpec(name, p.kind, p.default if default is None else default, p.unit, p.doc,
                     p.lo, p.hi, p.length, p.fidelity, p.choices, p.lo_open)


def resolve_alias(name: str) -> str:
    """``m1`` -> ``stage1.mass``, ``c2`` -> ``stage2.damping``; other names unchanged."""
    if len(name) >= 2 and name[0] in ALIASES and name[1:].isdigit():
        return f"{stage_name(int(name[1:]))}.{ALIASES[name[0]]}"
    return name


# ---------------------------------------------------------------------------------------------
# Validation of one value against its spec (errors name the field and the file)


def suggest(name: str, specs: Mapping[str, ParamSpec]) -> str:
    close = difflib.get_close_matches(name, list(specs), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def check_value(spec: ParamSpec, raw: Any, source: str) -> Any:
    where = f"{source}: {spec.name}"
    if spec.kind in ("floats", "ints"):
        if not isinstance(raw, (list, tuple)):
            raise ConfigError(f"{where}: expected a list of numbers, got {raw!r}")
        items = [_scalar(spec, x, where) for x in raw]
        if spec.length > 0 and len(items) != spec.length:
            raise ConfigError(f"{where}: expected {spec.length} values, got {len(items)}")
        if spec.length == -3 and len(items) % 3:
            raise ConfigError(f"{where}: expected x y z triples, got {len(items)} values")
        return items
    return _scalar(spec, raw, where)


def _scalar(spec: ParamSpec, raw: Any, where: str) -> Any:
    kind = spec.kind.rstrip("s") if spec.kind in ("floats", "ints") else spec.kind
    if kind == "str":
        if not isinstance(raw, str):
            raise ConfigError(f"{where}: expected a string, got {raw!r}")
        if spec.choices and raw not in spec.choices:
            raise ConfigError(f"{where}: must be one of {', '.join(spec.choices)}, got {raw!r}")
        return raw
    if kind == "bool":
        if not isinstance(raw, bool):
            raise ConfigError(f"{where}: expected true or false, got {raw!r}")
        return raw
    if isinstance(raw, str):
        raw = _numeric_string(raw)  # PyYAML reads 1.2e6 as a string; rcl reads a double
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {raw!r}")
    if kind == "int" and not float(raw).is_integer():
        raise ConfigError(f"{where}: expected an integer, got {raw!r}")
    x = float(raw)
    if not math.isfinite(x):
        raise ConfigError(f"{where}: must be finite, got {raw!r}")
    if x < spec.lo or (spec.lo_open and x <= spec.lo) or x > spec.hi:
        lo = "(" if spec.lo_open else "["
        raise ConfigError(f"{where}: {raw!r} is out of range {lo}{spec.lo:g}, {spec.hi:g}] "
                          f"{spec.unit}")
    return int(x) if kind == "int" else x


def _numeric_string(text: str) -> Any:
    try:
        return float(text)
    except ValueError:
        return text
