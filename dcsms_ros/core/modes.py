"""The paper's six control modes and which controllers each one enables."""

from __future__ import annotations

import enum

from dcsms_ros.errors import ModeError

#: Controller ids, also the ROS node names of the controller instances.
FB_STAGE1 = "fb_stage1"
FB_STAGE2 = "fb_stage2"
FF_STAGE1 = "ff_stage1"
CONTROLLERS: tuple[str, ...] = (FB_STAGE1, FB_STAGE2, FF_STAGE1)


class Mode(enum.Enum):
    """A control mode; ``value`` is the snake_case id used in service names."""

    PASSIVE = "passive"
    FBC = "fbc"
    FFC = "ffc"
    FBC_FFC = "fbc_ffc"
    DFBC = "dfbc"
    DFBC_FFC = "dfbc_ffc"

    @property
    def label(self) -> str:
        """Paper-style name, e.g. ``DFBC+FFC``."""
        return _LABELS[self]

    @property
    def controllers(self) -> frozenset[str]:
        """Controller ids enabled in this mode."""
        return _ENABLED[self]

    @property
    def feedback(self) -> bool:
        """Whether any feedback loop is closed (Passive and FFC are open loop: a stable plant
        driven through a stable filter cannot become unstable)."""
        return FB_STAGE1 in _ENABLED[self]


_LABELS = {
    Mode.PASSIVE: "Passive",
    Mode.FBC: "FBC",
    Mode.FFC: "FFC",
    Mode.FBC_FFC: "FBC+FFC",
    Mode.DFBC: "DFBC",
    Mode.DFBC_FFC: "DFBC+FFC",
}

_ENABLED = {
    Mode.PASSIVE: frozenset(),
    Mode.FBC: frozenset({FB_STAGE1}),
    Mode.FFC: frozenset({FF_STAGE1}),
    Mode.FBC_FFC: frozenset({FB_STAGE1, FF_STAGE1}),
    Mode.DFBC: frozenset({FB_STAGE1, FB_STAGE2}),
    Mode.DFBC_FFC: frozenset({FB_STAGE1, FB_STAGE2, FF_STAGE1}),
}

#: Modes in the paper's Table 4 order.
ALL_MODES: tuple[Mode, ...] = tuple(Mode)


def parse_mode(name: str) -> Mode:
    """Parse ``DFBC+FFC``, ``dfbc_ffc``, ``dfbc-ffc`` or ``FBC + FFC`` (any case) into a Mode.

    Raises
    ------
    ModeError
        For an unknown name; the message lists the valid names.
    """
    key = name.strip().lower().replace(" ", "").replace("+", "_").replace("-", "_")
    if key == "ffc_fbc":
        key = "fbc_ffc"
    if key == "dffc_dfbc" or key == "ffc_dfbc":
        key = "dfbc_ffc"
    for mode in Mode:
        if mode.value == key:
            return mode
    valid = ", ".join(m.label for m in Mode)
    raise ModeError(f"unknown mode {name!r}; valid modes: {valid}")


def controller_ids(num_stages: int) -> tuple[str, ...]:
    """Every controller of an N-stage cascade: ``fb_stage1`` … ``fb_stageN``, then ``ff_stage1``."""
    return (*(f"fb_stage{i}" for i in range(1, num_stages + 1)), FF_STAGE1)


def enabled_controllers(mode: Mode, num_stages: int) -> frozenset[str]:
    """Controllers a mode enables in an N-stage cascade.

    The paper's DFBC feeds back every table it has actuators under, so with N stages the dual
    (D) modes enable ``fb_stage1`` … ``fb_stageN``; single-stage modes use stage 1 only.
    """
    ids = set(mode.controllers)
    if FB_STAGE2 in ids:
        ids.discard(FB_STAGE2)
        ids.update(f"fb_stage{i}" for i in range(1, num_stages + 1))
    return frozenset(ids)


def controller_stage(controller: str) -> int:
    """1-based index of the stage a controller's actuators push (``ff_stage1`` -> 1)."""
    return int(controller.rsplit("stage", 1)[1])
