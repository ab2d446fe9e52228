"""Synthetic DCSMS bags for the analysis tests: a 2-DOF cascade simulated with scipy per mode."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import signal

from dcsms_ros import cdr
from dcsms_ros.analysis.bagio import LATCHED_QOS, open_bag
from dcsms_ros.analysis.reader import CONFIG_TOPIC, config_to_yaml
from dcsms_ros.core.config import load_config

M1, M2, K, C = 988.8, 748.8, 1.2e6, 1960.0
#: (label, skyhook damping on stage 1, on stage 2) in N*s/m: more damping, less motion.
MODES = (("Passive", 0.0, 0.0), ("FBC", 1.5e4, 0.0), ("DFBC", 1.5e4, 1.5e4),
         ("DFBC+FFC", 4e4, 4e4))


def plant(s1: float, s2: float) -> tuple[np.ndarray, ...]:
    """Continuous (A, B, C, D): state [e1, e2, v1, v2], input v_b, outputs v1, v2 (m/s)."""
    a = np.array([[0, 0, 1, 0], [0, 0, -1, 1],
                  [-K / M1, K / M1, -(2 * C + s1) / M1, C / M1],
                  [0, -K / M2, C / M2, -(C + s2) / M2]])
    b = np.array([[-1.0], [0.0], [C / M1], [0.0]])
    c = np.array([[0, 0, 1.0, 0], [0, 0, 0, 1.0]])
    return a, b, c, np.zeros((2, 1))


def simulate(fs: float, seconds: float, modes=MODES, seed: int = 3):
    """Ground and stage velocities (K,), (K, 2) and the per-sample mode index."""
    rng = np.random.default_rng(seed)
    n = int(seconds * fs)
    vb = 5e-6 * rng.standard_normal(n * len(modes))
    x = np.zeros(4)
    out = []
    forces = []
    for i, (_, s1, s2) in enumerate(modes):
        ad, bd, cd, dd, _ = signal.cont2discrete(plant(s1, s2), 1 / fs, "zoh")
        u = vb[i * n:(i + 1) * n]
        _, y, xs = signal.dlsim((ad, bd, cd, dd, 1 / fs), u, x0=x)
        x = ad @ xs[-1] + bd[:, 0] * u[-1]
        out.append(y)
        forces.append(np.column_stack([-s1 * y[:, 0], -s2 * y[:, 1]]))
    return vb, np.vstack(out), np.vstack(forces), n


def write_bag(path: Path, fs: float = 500.0, seconds: float = 20.0, modes=MODES,
              config: bool = True, storage: str = "mcap", repeat: tuple[int, ...] = ()) -> Path:
    """Write a multi-mode bag: velocities, applied forces, /dcsms/mode and /dcsms/config;
    ``repeat``: samples recorded twice in a row in every stream (lockstep retransmissions)."""
    vb, v, f, n = simulate(fs, seconds, modes)
    dt_ns = int(round(1e9 / fs))
    rows = np.sort(np.r_[np.arange(vb.size), np.asarray(repeat, dtype=np.int64)])
    vb, v, f = vb[rows], v[rows], f[rows]
    k = vb.size
    t = 1_000_000_000 + rows * dt_ns
    zeros = np.zeros((k, 6))
    with open_bag(path, storage) as w:
        w.add_topic("/dcsms/mode", "std_msgs/msg/String", LATCHED_QOS)
        w.add_topic(CONFIG_TOPIC, "std_msgs/msg/String", LATCHED_QOS)
        if config:
            w.write(CONFIG_TOPIC, int(t[0]), cdr.encode_string(config_to_yaml(load_config())))
        for i, (label, _, _) in enumerate(modes):
            w.write("/dcsms/mode", 1_000_000_000 + i * n * dt_ns, cdr.encode_string(label))
        for body, vel in (("ground", vb), ("stage1", v[:, 0]), ("stage2", v[:, 1])):
            tw = zeros.copy()
            tw[:, 2] = vel
            topic = f"/dcsms/velocity/{body}"
            w.add_topic(topic, cdr.TWIST_STAMPED)
            w.write_many(topic, t, cdr.encode_stamped(cdr.TWIST_STAMPED, t, body, tw))
        w.add_topic("/dcsms/actuators/applied", cdr.JOINT_STATE)
        w.write_many("/dcsms/actuators/applied", t,
                     cdr.encode_joint_state(t, "", ["stage1", "stage2"], effort=f))
    return path
