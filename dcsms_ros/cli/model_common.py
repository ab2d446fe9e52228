"""Helpers shared by the ``dcsms model`` sub-commands (arguments, grids, number formats)."""

from __future__ import annotations

import argparse
import math

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.model import axis_names
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.errors import ConfigError, DcsmsError

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

TWO_PI = 2.0 * math.pi
#: Most rows a plain-text frequency table prints (``--json`` always has every point).
MAX_TABLE_ROWS = 41
#: What the default (discrete) analysis covers, for headers.
AS_RUNS = ("the discrete loop as it runs (plant ZOH, geophones, LF extension, decoupling, "
           "controller sections, allocation)")
IDEAL = "the paper's continuous model (Eq. 4/10: ideal sensors, continuous controllers)"


def mode_arg(text: str) -> Mode:
    """argparse type: a mode name (``DFBC+FFC``, ``dfbc_ffc`` ...)."""
    try:
        return parse_mode(text)
    except DcsmsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def float_list(text: str) -> list[float]:
    """argparse type: comma-separated finite numbers."""
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def add_ideal(p: argparse.ArgumentParser) -> None:
    """``--ideal``: the paper's continuous model instead of the loop as it runs."""
    p.add_argument("--ideal", action="store_true",
                   help="the paper's continuous model (Eq. 4/10: ideal sensors, continuous "
                   "controllers) instead of the discrete loop as it runs")


def add_axis_and_grid(p: argparse.ArgumentParser) -> None:
    """``--axis`` and the log frequency grid ``--fmin --fmax --points``."""
    p.add_argument("--axis", default="z", choices=("x", "y", "z", "rx", "ry", "rz"),
                   help="axis of a 6dof model (1dof: z only; default z)")
    p.add_argument("--fmin", type=float, default=0.1, help="lowest frequency, Hz (default 0.1)")
    p.add_argument("--fmax", type=float, default=100.0, help="highest frequency, Hz (default 100)")
    p.add_argument("--points", type=int, default=400,
                   help="log-spaced frequency points (default 400)")


def grid(args: argparse.Namespace, nyquist: float = math.inf) -> Array:
    """The ``--fmin/--fmax/--points`` grid (Hz); a discrete model needs ``fmax < nyquist``."""
    if not (0 < args.fmin < args.fmax and math.isfinite(args.fmax)):
        raise ConfigError(f"need 0 < --fmin < --fmax, got {args.fmin:g} and {args.fmax:g}")
    if args.fmax >= nyquist:
        raise ConfigError(f"--fmax {args.fmax:g}: must be below the Nyquist frequency "
                          f"{nyquist:g} Hz of the loop as it runs (or use --ideal)")
    if not 2 <= args.points <= 100_000:
        raise ConfigError(f"--points must be in [2, 100000], got {args.points}")
    return np.logspace(math.log10(args.fmin), math.log10(args.fmax), args.points)


def check_axis(cfg: SystemConfig, axis: str) -> None:
    """Refuse an axis the model does not have (1dof: z only)."""
    if axis not in axis_names(cfg.plant.dof):
        raise ConfigError(f"--axis {axis}: a {cfg.plant.fidelity} model has only "
                          f"{', '.join(axis_names(cfg.plant.dof))}")


def db(h: CArray) -> Array:
    """20 log10 |h| (dB), floored at -6000 dB."""
    return np.asarray(20.0 * np.log10(np.maximum(np.abs(h), 1e-300)))


def phase(h: CArray) -> Array:
    """Unwrapped phase, degrees."""
    return np.asarray(np.degrees(np.unwrap(np.angle(h))))


def cell(x: float, fmt: str) -> str:
    """A number for a text table: ``inf``, ``-`` for NaN."""
    return format(x, fmt) if math.isfinite(x) else ("inf" if math.isinf(x) else "-")


__all__ = ["AS_RUNS", "IDEAL", "MAX_TABLE_ROWS", "TWO_PI", "Array", "CArray", "add_axis_and_grid",
           "add_ideal", "cell", "check_axis", "db", "float_list", "grid", "mode_arg", "phase"]
