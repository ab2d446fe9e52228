"""Measured frequency responses and the parameters ``dcsms fit`` can identify.

Data: every usable bin (:mod:`.frf`: random error of |H1| at most 10 %) of the mobility of excited
segments and of the transmissibility of the segments, in 0.5-100 Hz (:func:`collect`). The fit
itself, what the data can identify and the standard deviations: :mod:`.identify_fit`.

Parameters (``--params``, :func:`parse_params`):

* 1-DOF: ``m<i>`` (kg), ``k<i>`` (N/m), ``c<i>`` (N*s/m) of stage i;
* 6-DOF: ``m<i>`` and ``k<i><a>``, ``c<i><a>`` for a = x, y, z: the suspension under stage i
  along that axis, summed over its mounts (each mount's value scaled alike);
* the geophones (every channel alike): ``fg`` natural frequency (Hz), ``zg`` damping ratio
  (-), ``sg`` sensitivity (V/(m/s)): the true values behind the readings, which the rig
  converted with the configured ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import frf as frfmod
from dcsms_ros.analysis.reader import BagData, Progress, config_from_yaml, read_bag
from dcsms_ros.analysis.segments import (
    MIN_SEGMENT_S,
    SETTLE_S,
    align,
    split_excited,
    split_segments,
)
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import DcsmsError

#: Smallest random error a bin is weighted with (a model error of 0.1 % is not noise).
MIN_EPS = 1e-3

#: Geophone parameters: name -> (configuration key, unit).
SENSOR_PARAMS = {"fg": ("sensors.natural_frequency_hz", "Hz"), "zg": ("sensors.damping_ratio", "-"),
           "sg": ("sensors.sensitivity_v_per_mps", "V/(m/s)")}
#: Suspension and mass parameters: letter -> (key suffix, unit).
PHYSICAL_PARAMS = {"m": ("mass", "kg"), "k": ("stiffness", "N/m"), "c": ("damping", "N*s/m")}


@dataclass(frozen=True)
class Param:
    """One fitted parameter: ``name`` (``m1``, ``k2``, ``c1x``, ``fg`` ...), ``unit``, ``kind``
    (``m``, ``k``, ``c`` or the sensor name), ``stage`` (1-based, 0 for the geophones) and
    ``axis`` (6-DOF suspensions; "" otherwise)."""

    name: str
    unit: str
    kind: str
    stage: int = 0
    axis: str = ""

    def value(self, cfg: SystemConfig) -> float:
        """The parameter's value in ``cfg`` (its unit)."""
        flat = cfg.params or {}
        if self.kind in SENSOR_PARAMS:
            return float(flat[SENSOR_PARAMS[self.kind][0]])
        key = f"stage{self.stage}."
        if self.axis:
            j = "xyz".index(self.axis)
            what = "stiffness" if self.kind == "k" else "damping"
            return float(sum(flat[key + f"mounts.{what}"][j::3]))
        return float(flat[key + PHYSICAL_PARAMS[self.kind][0]])

    def write(self, flat: dict[str, Any], cfg: SystemConfig, value: float) -> None:
        """Put ``value`` into the flat parameters ``flat`` (of ``cfg``'s layout)."""
        if self.kind in SENSOR_PARAMS:
            flat[SENSOR_PARAMS[self.kind][0]] = value
            return
        key = f"stage{self.stage}."
        if not self.axis:
            flat[key + PHYSICAL_PARAMS[self.kind][0]] = value
            return
        j = "xyz".index(self.axis)
        name = key + f"mounts.{'stiffness' if self.kind == 'k' else 'damping'}"
        old = list(flat[name])
        scale = value / self.value(cfg)
        flat[name] = [v * scale if i % 3 == j else v for i, v in enumerate(old)]


def parse_params(cfg: SystemConfig, text: str | None) -> list[Param]:
    """``m1,k1,c1,...`` (or the defaults: every mass, stiffness and damping in 1-DOF; every
    suspension's stiffness and damping along x, y and z in 6-DOF).

    Raises
    ------
    DcsmsError
        An unknown name, a stage that does not exist, a name given twice, or a per-axis name
        in 1-DOF (or a plain ``k1``/``c1`` in 6-DOF).
    """
    n, six = cfg.plant.num_stages, cfg.plant.dof == 6
    if text is None:
        names = ([f"{k}{i}{a}" for i in range(1, n + 1) for k in "kc" for a in "xyz"] if six
                 else [f"{k}{i}" for i in range(1, n + 1) for k in "mkc"])
    else:
        names = [t.strip() for t in text.split(",") if t.strip()]
    out: list[Param] = [_param(name, n, six) for name in names]
    dup = {p.name for p in out if sum(q.name == p.name for q in out) > 1}
    if dup:
        raise DcsmsError(f"--params: {', '.join(sorted(dup))} given twice")
    if not out:
        raise DcsmsError("--params: no parameter named")
    return out


def _param(name: str, n: int, six: bool) -> Param:
    if name in SENSOR_PARAMS:
        return Param(name, SENSOR_PARAMS[name][1], name)
    kind, rest = name[:1], name[1:]
    axis = ""
    if rest and rest[-1] in "xyz":
        rest, axis = rest[:-1], rest[-1]
    hint = ("m<i>, k<i>, c<i> (1dof), m<i>, k<i><x|y|z>, c<i><x|y|z> (6dof), fg, zg, sg")
    if kind not in PHYSICAL_PARAMS or not rest.isdigit():
        raise DcsmsError(f"--params: unknown parameter {name!r}; expected {hint}")
    stage = int(rest)
    if not 1 <= stage <= n:
        raise DcsmsError(f"--params {name}: stage{stage} does not exist ({n} stages)")
    if kind == "m" and axis:
        raise DcsmsError(f"--params {name}: a mass has no axis; use m{stage}")
    if kind in "kc" and six != bool(axis):
        raise DcsmsError(f"--params {name}: " + (
            f"a 6dof suspension is fitted per axis: {kind}{stage}x, {kind}{stage}y, "
            f"{kind}{stage}z" if six else f"a 1dof plant has no axes: use {kind}{stage}"))
    return Param(name, PHYSICAL_PARAMS[kind][1], kind, stage, axis)


@dataclass
class Measured:
    """One measured response of one stage, restricted to its usable bins.

    Attributes
    ----------
    kind : str
        ``mobility`` ((m/s)/N) or ``transmissibility`` (-).
    mode : Mode
    axis : str
    stage : int
        Output stage (1-based).
    excited : int
        Excited stage for a mobility (0 otherwise).
    f, h, eps, sxx : ndarray, shape (F,)
        Bin frequencies (Hz), H1, random error of |H1|, input auto-spectrum.
    fs : float
    nperseg : int
    label : str
        Segment (bag, mode, excitation) for reports.
    all_f, all_h : ndarray
        Every bin of the compare range (for the plots).
    """

    kind: str
    mode: Mode
    axis: str
    stage: int
    excited: int
    f: np.ndarray
    h: np.ndarray
    eps: np.ndarray
    sxx: np.ndarray
    fs: float
    nperseg: int
    label: str
    all_f: np.ndarray = field(default_factory=lambda: np.zeros(0))
    all_h: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))

    @property
    def name(self) -> str:
        src = f"F{self.excited}" if self.kind == "mobility" else "v_b"
        return f"v_p{self.stage}/{src} {self.axis}"


@dataclass
class Collected:
    """What :func:`collect` found: the responses, the configuration they ran with, and notes."""

    measured: list[Measured]
    cfg: SystemConfig
    truth: bool
    warnings: list[str] = field(default_factory=list)
    segments: list[dict[str, Any]] = field(default_factory=list)


def collect(bags: Sequence[str | Path], config: SystemConfig | None = None,
            kinds: Sequence[str] = frfmod.KINDS, settle_s: float = SETTLE_S,
            progress: Progress | None = None) -> Collected:
    """Measured responses of every segment of ``bags`` (module docstring).

    Parameters
    ----------
    bags : sequence of path
    config : SystemConfig, optional
        The configuration the rig ran with, instead of the one recorded on ``/dcsms/config``.
    kinds : sequence of str
        Which responses to use (``mobility``, ``transmissibility``).

    Raises
    ------
    DcsmsError
        No configuration, bags recorded with different configurations, or not one usable bin.
    """
    out: list[Measured] = []
    warnings: list[str] = []
    segs_js: list[dict[str, Any]] = []
    cfg_used: SystemConfig | None = config
    truth = False
    texts: set[str] = set()
    for b in bags:
        data = read_bag(b, progress)
        truth = truth or data.source == "truth"
        if config is None:
            if not data.config_text:
                raise DcsmsError(f"{data.path}: no /dcsms/config: give the configuration the rig "
                                 "ran with (--config)")
            texts.add(data.config_text)
            if len(texts) > 1:
                raise DcsmsError(f"{data.path}: recorded with another configuration than the "
                                 "bags before it; fit bags of one configuration (or --config)")
            cfg_used = config_from_yaml(data.config_text, f"{data.path}:/dcsms/config")
        assert cfg_used is not None
        out += _bag_responses(data, cfg_used, kinds, settle_s, warnings, segs_js)
    if cfg_used is None:
        raise DcsmsError("no bags")
    if not out:
        raise DcsmsError("no usable bins in the bags (no segment with a known mode and a "
                         "response whose random error is <= 10 %)")
    return Collected(out, cfg_used, truth, warnings, segs_js)


def _bag_responses(data: BagData, cfg: SystemConfig, kinds: Sequence[str], settle_s: float,
                   warnings: list[str], segs_js: list[dict[str, Any]]) -> list[Measured]:
    out: list[Measured] = []
    ref = next(iter(data.bodies.values()))
    if ref.stamp_ns.size == 0:
        return out
    axes = ["z"] if cfg.plant.dof == 1 else ["x", "y", "z"]
    segs = split_segments(data.modes, int(ref.stamp_ns[0]), int(ref.stamp_ns[-1]), settle_s)
    for seg in split_excited(segs, data.excitation, settle_s):
        where = f"{data.path} [{seg.label} @ {seg.t0_ns * 1e-9:.2f} s]"
        if seg.mode is None or seg.duration_s < MIN_SEGMENT_S:
            warnings.append(f"{where}: no known mode or shorter than {MIN_SEGMENT_S:g} s; "
                            "not used")
            continue
        al = align(data, seg)
        if al.stamp_ns.size < 64 or al.fs <= 0:
            continue
        nper = est.choose_nperseg(al.fs, al.stamp_ns.size)
        stages = sorted((s for s in al.bodies if s != "ground"), key=lambda s: int(s[5:]))
        outputs = {s: al.bodies[s] for s in stages}
        frame = data.excitation.frame_id if data.excitation is not None else ""
        exc_stage = int(frame[5:]) if seg.excited and frame[5:].isdigit() else 0
        label = f"{data.path.name}: {seg.label}" + (f" + excitation {frame}" if seg.excited
                                                    else "")
        used = {}
        for a in axes:
            j = "xyz".index(a)
            ests = []
            if "transmissibility" in kinds and "ground" in al.bodies:
                ests.append(frfmod.estimate("transmissibility", al.bodies["ground"][:, j],
                                            outputs, a, al.fs, nper, "", ""))
            if ("mobility" in kinds and al.excitation is not None
                    and a in frfmod.excited_axes(al.excitation, [a])):
                ests.append(frfmod.estimate("mobility", al.excitation[:, j], outputs, a,
                                            al.fs, nper, "", ""))
            for e in ests:
                for i, s in enumerate(e.stages):
                    ok = e.usable(i)
                    t = e.tfs[i]
                    used[f"{e.kind} {s} {a}"] = int(ok.sum())
                    if not ok.any():
                        continue
                    band = ((t.f >= frfmod.COMPARE_RANGE_HZ[0])
                            & (t.f <= frfmod.COMPARE_RANGE_HZ[1]))
                    eps = est.h1_random_error(t.coherence, t.averages)
                    assert e.sxx is not None
                    out.append(Measured(
                        e.kind, seg.mode, a, int(s[5:]),
                        exc_stage if e.kind == "mobility" else 0, t.f[ok], t.h[ok],
                        np.maximum(eps[ok], MIN_EPS), e.sxx[ok], al.fs, nper, label,
                        t.f[band], t.h[band]))
        segs_js.append({"segment": label, "t_start_s": seg.t0_ns * 1e-9,
                        "duration_s": seg.duration_s, "usable_bins": used})
    return out


__all__ = ["PHYSICAL_PARAMS", "SENSOR_PARAMS", "Collected", "Measured", "Param", "collect",
           "parse_params"]
