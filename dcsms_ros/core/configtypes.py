"""The configuration's frozen dataclasses: plant and stages, sensors, actuators, controllers,
timeouts, supervisor and disturbances (SI units). :mod:`.config` builds them from params
files and flat dotted names, checked against :mod:`.schema`; the nodes receive the same
objects, so the numeric core never sees ROS types.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Transducers:
    """Sensors or actuators on one body: positions (m, world) and unit directions, shape (n, 3)."""

    position: tuple[Vec3, ...] = ()
    direction: tuple[Vec3, ...] = ()


@dataclass(frozen=True)
class Mounts:
    """Springs under a stage: positions (m, world), stiffness (N/m) and damping (N*s/m) along
    x, y, z per mount, each of shape (n, 3)."""

    position: tuple[Vec3, ...] = ()
    stiffness: tuple[Vec3, ...] = ()
    damping: tuple[Vec3, ...] = ()


@dataclass(frozen=True)
class StageConfig:
    """One stage. In 1dof ``stiffness``/``damping`` are given; in 6dof they are the sums of the
    mounts' z values (so the vertical analytics still apply)."""

    name: str
    mass: float  # kg
    stiffness: float  # N/m, vertical, all mounts
    damping: float  # N*s/m, vertical, all mounts
    actuator_count: int  # 1dof: lumped actuators; 6dof: len(actuators.position)
    inertia: Vec3 = (1.0, 1.0, 1.0)  # kg*m^2 about the CoM
    com: Vec3 = (0.0, 0.0, 0.0)  # m, world; reference point
    mounts: Mounts = Mounts()
    sensors: Transducers = Transducers()
    actuators: Transducers = Transducers()


@dataclass(frozen=True)
class PlantConfig:
    fidelity: str  # "1dof" | "6dof"
    rate_hz: float  # Hz
    stages: tuple[StageConfig, ...]
    ground_sensors: Transducers = Transducers()

    @property
    def dt(self) -> float:
        """Sample period in s."""
        return 1.0 / self.rate_hz

    @property
    def num_stages(self) -> int:
        return len(self.stages)

    @property
    def dof(self) -> int:
        """Degrees of freedom per body: 1 (z) or 6 (x y z rx ry rz)."""
        return 1 if self.fidelity == "1dof" else 6


@dataclass(frozen=True)
class SensorConfig:
    natural_frequency_hz: float = 4.5
    damping_ratio: float = 0.42
    sensitivity_v_per_mps: float = 100.4
    noise_asd: float = 1e-9  # m/s/sqrt(Hz)
    dynamics: bool = True
    extension_hz: float = 0.5
    extension_damping: float = 0.707


@dataclass(frozen=True)
class ActuatorConfig:
    force_limit_n: float = 100.0  # N per actuator


@dataclass(frozen=True)
class FeedbackConfig:
    """Velocity feedback of one stage: force = -gain * filters(s) * velocity, per axis."""

    gain: tuple[float, ...]  # 6 values: N*s/m (x y z), N*m*s/rad (rx ry rz)
    highpass_hz: float = 0.3
    highpass_order: int = 1
    lowpass_hz: float = 150.0
    lowpass_order: int = 2
    notch_hz: float = 0.0
    notch_q: float = 5.0
    lead_hz: float = 0.0
    lag_hz: float = 0.0


@dataclass(frozen=True)
class FeedforwardConfig:
    """Ground feedforward into the stage-1 actuators:
    force = -gain * (c1 + k1/s) * HP * LP * v_b."""

    gain: float = 0.9
    highpass_hz: float = 0.5
    highpass_order: int = 2
    lowpass_hz: float = 150.0
    lowpass_order: int = 2


@dataclass(frozen=True)
class ControlConfig:
    fade_time_s: float = 0.5
    input_timeout_s: float = 0.01
    lockstep_timeout_s: float = 0.5
    trip_rms_mps: float = 1e-3
    trip_band_hz: tuple[float, float] = (1.0, 200.0)
    trip_window_s: float = 0.2


@dataclass(frozen=True)
class SupervisorConfig:
    """``supervisor.*`` of the schema (SI units; :class:`~.supervisor.SupervisorSettings`
    documents each)."""

    enabled: bool = True
    ride_mode: str = "fbc"
    ride_ground_mps: float = 2e-4
    ride_force_ratio: float = 0.8
    quiet_fraction: float = 0.5
    recover_after_s: float = 5.0
    settle_s: float = 1.0
    excess_ratio: float = 4.0
    growth_per_s: float = 2.0
    floor_memory_s: float = 2.0
    hold_s: float = 2.0
    backoff: float = 2.0
    max_attempts: int = 3
    attempts_window_s: float = 120.0


@dataclass(frozen=True)
class DisturbanceConfig:
    seed: int = 1
    ground_rms_mps: Vec3 = (2e-6, 2e-6, 5e-6)
    ground_band_hz: tuple[float, float] = (0.5, 100.0)
    force_rms_n: float = 0.1
    force_band_hz: tuple[float, float] = (0.5, 100.0)


@dataclass(frozen=True)
class SystemConfig:
    """Everything one simulation or graph needs. ``feedback[i]`` belongs to ``plant.stages[i]``."""

    plant: PlantConfig
    sensors: SensorConfig
    actuators: ActuatorConfig
    feedback: tuple[FeedbackConfig, ...]
    feedforward: FeedforwardConfig
    control: ControlConfig
    disturbance: DisturbanceConfig
    supervisor: SupervisorConfig = SupervisorConfig()
    source: str = "<defaults>"
    params: Mapping[str, Any] | None = None  # the flat, validated values (dotted names)


__all__ = [
    "ActuatorConfig",
    "ControlConfig",
    "DisturbanceConfig",
    "FeedbackConfig",
    "FeedforwardConfig",
    "Mounts",
    "PlantConfig",
    "SensorConfig",
    "StageConfig",
    "SupervisorConfig",
    "SystemConfig",
    "Transducers",
    "Vec3",
]
