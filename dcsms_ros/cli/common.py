"""Options and helpers shared by the ``dcsms`` sub-commands.

``--config FILE``, ``--set NAME=VALUE`` (repeatable), ``--json`` and ``--plot DIR`` mean the same
everywhere; :func:`load_cfg` turns the first two into a validated
:class:`~dcsms_ros.core.config.SystemConfig`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from dcsms_ros import core
from dcsms_ros.core.config import SystemConfig, load_config, parse_override, with_overrides
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.core.safety import MIN_GM_DB, MIN_PM_DEG
from dcsms_ros.errors import ConfigError, DcsmsError
from dcsms_ros.jsonutil import jsonable

PACKAGE = "dcsms_ros"
DEFAULT_PRESET = "table1.yaml"
#: Without a terminal, seconds between two progress lines (and before the first).
PIPE_PERIOD_S = 10.0
#: Bags with fewer messages finish in about a second: no progress bar for them.
PROGRESS_MIN_MESSAGES = 200_000


def share_candidates() -> Iterator[Path]:
    """Directories that may hold this package's ``config/`` and ``launch/``, best first.

    1. the source tree (a checkout, or ``pip install -e .``);
    2. the ament index (a sourced colcon install: ``share/dcsms_ros``);
    3. ``share/dcsms_ros`` beside the installed package (colcon install without sourcing) and
       under ``sys.prefix`` (``pip install .`` puts data files there).

    A generator, so the ament index is only consulted when the source tree has no match.
    """
    here = Path(__file__).resolve()
    yield here.parents[2]
    try:
        from ament_index_python.packages import (  # noqa: PLC0415 - optional dependency
            PackageNotFoundError,
            get_package_share_directory,
        )
    except ImportError:  # ament_index_python is optional for the numeric commands
        pass
    else:
        try:
            yield Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH is not set
            pass
    # <prefix>/lib/pythonX.Y/site-packages/dcsms_ros/cli/common.py -> <prefix>
    if len(here.parents) > 5:
        yield here.parents[5] / "share" / PACKAGE
    yield Path(sys.prefix) / "share" / PACKAGE


def find_share_file(relative: str) -> Path:
    """Locate a packaged file such as ``config/table1.yaml`` (see :func:`share_candidates`).

    Raises
    ------
    ConfigError
        If no candidate directory holds it.
    """
    for base in share_candidates():
        path = base / relative
        if path.is_file():
            return path
    raise ConfigError(f"cannot find packaged file '{relative}' (looked in the source tree, the "
                      f"ament index and {sys.prefix}/share/{PACKAGE})")


def default_config_path() -> Path:
    """The paper's Table 1 preset, ``config/table1.yaml``."""
    return find_share_file(f"config/{DEFAULT_PRESET}")


def add_config_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--config FILE`` and ``--set NAME=VALUE`` (repeatable)."""
    parser.add_argument("--config", metavar="FILE", type=Path, default=None,
                        help=f"ROS 2 params YAML (default: the packaged config/{DEFAULT_PRESET})")
    parser.add_argument("--set", metavar="NAME=VALUE", action="append", default=[],
                        dest="overrides",
                        help="override one parameter after the file, e.g. --set m1=1200 or "
                        "--set feedback.stage1.gain=[0,0,2e4,0,0,0]; dotted names or the "
                        "aliases m1 m2 c1 c2 k1 k2 (repeatable)")


def add_output_options(parser: argparse.ArgumentParser, plot: bool = True) -> None:
    """Add ``--json`` (machine-readable stdout) and, if ``plot``, ``--plot DIR``."""
    parser.add_argument("--json", action="store_true",
                        help="print JSON on stdout instead of a table")
    if plot:
        parser.add_argument("--plot", metavar="DIR", type=Path, default=None,
                            help="write PNG figures into DIR (created if needed)")


def add_margin_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--min-gm DB`` and ``--min-pm DEG`` (the safety check's minimum margins)."""
    parser.add_argument("--min-gm", type=float, default=MIN_GM_DB, metavar="DB",
                        help=f"minimum gain margin of every loop and disk, dB (default "
                        f"{MIN_GM_DB:g})")
    parser.add_argument("--min-pm", type=float, default=MIN_PM_DEG, metavar="DEG",
                        help=f"minimum phase margin of every loop and disk, deg (default "
                        f"{MIN_PM_DEG:g})")


def load_cfg(args: argparse.Namespace) -> SystemConfig:
    """The configuration named by ``--config`` with every ``--set`` applied and validated."""
    path = args.config if args.config is not None else default_config_path()
    overrides = dict(parse_override(text) for text in args.overrides)
    return load_config(path, overrides)


def parse_schedule(text: str) -> list[tuple[float, Any]]:
    """``"T:MODE,T:MODE"`` -> [(time s, Mode)], sorted; raises DcsmsError on bad items."""
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        t_text, sep, name = item.partition(":")
        try:
            t = float(t_text)
        except ValueError:
            t = float("nan")
        if not sep or not t >= 0.0:
            raise DcsmsError(f"--schedule {item!r}: expected TIME:MODE with TIME >= 0 s")
        out.append((t, parse_mode(name)))
    return sorted(out, key=lambda e: e[0])


def _cached_verdict(cfg: SystemConfig, what: str,
                    compute: Callable[[], list[str]]) -> list[str]:
    """``compute()`` (lines of text), kept in ``$XDG_CACHE_HOME/dcsms`` (default ``~/.cache``)
    under the hash of ``what``, the configuration and the model's code (every module of
    ``dcsms_ros.core``): a verdict is a function of those alone, and computing it means
    importing python-control and the loop model (1.1-1.5 s) before a run can start."""
    src = b"".join(f.read_bytes() for f in sorted(Path(core.__file__).parent.glob("*.py")))
    key = hashlib.sha256(src + what.encode()
                         + json.dumps(cfg.params, sort_keys=True, default=str).encode())
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dcsms" / \
        f"check-{key.hexdigest()[:32]}.json"
    try:
        return [str(x) for x in json.loads(cache.read_text())]
    except (OSError, ValueError, TypeError):
        pass
    lines = compute()
    try:
        cache.parent.mkdir(parents=True, exist_ok=True)
        tmp = cache.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(lines))
        tmp.replace(cache)
    except OSError:
        pass  # a read-only home: no cache, same verdict
    return lines


def model_check_lines(cfg: SystemConfig) -> list[str]:
    """The model's verdict on every mode: one line per failing mode, or one line saying all six
    are stable with margins (cached: :func:`_cached_verdict`)."""
    def compute() -> list[str]:
        # deferred: python-control and the loop model, only when the verdict is not cached
        from dcsms_ros.core.check import check_config  # noqa: PLC0415 - deferred for --help

        bad = [c for c in check_config(cfg) if not c.ok]
        return [f"model check: {c.mode.label}: {'; '.join(c.failures)}" for c in bad] or [
            "model check: all six modes stable with margins"]

    return _cached_verdict(cfg, "model check", compute)


def print_model_check(cfg: SystemConfig) -> None:
    """Print :func:`model_check_lines` (and go on)."""
    for line in model_check_lines(cfg):
        print(line, flush=True)


def start_refusal(cfg: SystemConfig, mode: Mode, realtime: bool = False) -> str | None:
    """Why the graph must not start in ``mode``: the model calls it unstable, or
    (``realtime``) forces ``control.input_timeout_s`` late destabilise it; None if it may
    (cached: :func:`_cached_verdict`)."""
    def compute() -> list[str]:
        # deferred: python-control and the loop model, only when the verdict is not cached
        from dcsms_ros.core.check import unstable_reason  # noqa: PLC0415 - deferred for --help
        from dcsms_ros.core.margins import late_force_reason  # noqa: PLC0415 - as above

        reason = unstable_reason(cfg, mode)
        if reason is None and realtime:
            reason = late_force_reason(cfg, mode)
        return [] if reason is None else [reason]

    lines = _cached_verdict(cfg, f"start {mode.label} realtime={realtime}", compute)
    return lines[0] if lines else None


def refuse_unstable_start(cfg: SystemConfig, mode: Mode, allow_unstable: bool,
                          realtime: bool = False) -> None:
    """Raise :class:`DcsmsError` when :func:`start_refusal` has a reason and
    ``--allow-unstable`` was not given (the guard a switch passes)."""
    if allow_unstable or mode is Mode.PASSIVE:
        return
    reason = start_refusal(cfg, mode, realtime)
    if reason is not None:
        raise DcsmsError(f"--mode {mode.label}: {reason}; refused (--allow-unstable runs it)")


def parse_excitations(cfg: Any, texts: Sequence[str]) -> list[Any]:
    """``--excite`` texts -> checked :class:`~dcsms_ros.core.excitation.ExcitationSpec` list."""
    # deferred: python-control (filters), not for `dcsms --help`
    from dcsms_ros.core.excitation import (  # noqa: PLC0415 - deferred for --help
        check_specs,
        parse_spec,
    )

    specs = [parse_spec(t) for t in texts]
    check_specs(cfg, specs)
    return specs


def plant_config(cfg: Any, texts: Sequence[str]) -> Any:
    """The plant of ``--plant-set NAME=VALUE`` overrides (None without any), checked against
    ``cfg`` (:func:`~dcsms_ros.core.simulator.check_plant`)."""
    # deferred: python-control (sensors, filters), not for `dcsms --help`
    from dcsms_ros.core.simulator import check_plant  # noqa: PLC0415 - deferred for --help

    if not texts:
        return None
    plant = with_overrides(cfg, dict(parse_override(t) for t in texts))
    check_plant(cfg, plant)
    return plant


class ProgressBar:
    """Progress of a long bag on stderr: a redrawn bar on a terminal; elsewhere (a log, a pipe)
    a whole line every :data:`PIPE_PERIOD_S`, the first after that long, so a bag that fails
    early gives its one-line error and nothing else."""

    def __init__(self, stream: Any = None) -> None:
        self._stream = stream  # None: sys.stderr as it is when the bar is first drawn
        self.tty: bool | None = None
        self.last = time.monotonic()
        self.shown = False

    @property
    def stream(self) -> Any:
        return self._stream if self._stream is not None else sys.stderr

    def __call__(self, done: int, total: int) -> None:
        if total < PROGRESS_MIN_MESSAGES:
            return
        if self.tty is None:
            self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
            if self.tty:
                self.last = 0.0
        now = time.monotonic()
        period = 0.2 if self.tty else PIPE_PERIOD_S
        if now - self.last < period and (done < total or not self.shown):
            return
        self.last = now
        frac = min(done / total, 1.0) if total else 1.0
        bar = "#" * int(30 * frac)
        text = f"reading [{bar:<30}] {100 * frac:5.1f}% ({done}/{total} msgs)"
        self.stream.write(f"\r{text}" + ("\n" if done >= total else "") if self.tty
                          else text + "\n")
        self.shown = True
        self.stream.flush()


def print_json(obj: Any) -> None:
    """Print ``obj`` as one strict-JSON document on stdout."""
    print(json.dumps(jsonable(obj), allow_nan=False))


def plot_dir(path: Path) -> Path:
    """Create the ``--plot`` directory and select the non-interactive matplotlib backend."""
    import matplotlib  # noqa: PLC0415 - deferred: matplotlib

    matplotlib.use("Agg")  # no display in CI or over ssh; must precede pyplot's import
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DcsmsError(f"--plot {path}: cannot create directory: {exc.strerror}") from None
    return path


__all__ = [
    "ProgressBar",
    "add_config_options",
    "add_margin_options",
    "add_output_options",
    "default_config_path",
    "find_share_file",
    "jsonable",
    "load_cfg",
    "model_check_lines",
    "parse_excitations",
    "parse_schedule",
    "plant_config",
    "plot_dir",
    "print_json",
    "print_model_check",
    "refuse_unstable_start",
    "share_candidates",
    "start_refusal",
]
