"""The paper's six control modes, which controllers each one enables, and controller ids."""

from __future__ import annotations

import enum
import functools
import re
from dataclasses import dataclass

from dcsms_ros.errors import ConfigError, ModeError

#: Kinds of controller: velocity feedback of a stage, feedforward of the ground velocity.
FEEDBACK, FEEDFORWARD = "fb", "ff"
_ID = re.compile(r"(fb|ff)_stage([1-9][0-9]*)")


@dataclass(frozen=True, order=True)
class ControllerId:
    """Who a controller is: its kind and the 1-based stage its actuators push.

    ``str()`` gives the name used on the wire, unchanged: node name, topic and service part,
    key of the per-controller maps (``fb_stage2``, ``ff_stage1``); :meth:`parse` reads it
    back. Ids sort feedback first, then by stage (``kind`` "fb" < "ff"): the order of
    :func:`controller_ids`, in which the plant and the batch engine sum the forces.

    Parameters
    ----------
    kind : str
        :data:`FEEDBACK` (``"fb"``) or :data:`FEEDFORWARD` (``"ff"``).
    stage : int
        Stage whose actuators it drives, 1-based; feedforward exists on stage 1 only (the
        paper's FFC drives the first stage from the ground velocity).

    Raises
    ------
    ConfigError
        Another kind, a stage below 1, or feedforward on a stage other than 1.
    """

    kind: str
    stage: int

    def __post_init__(self) -> None:
        if (self.kind not in (FEEDBACK, FEEDFORWARD) or not isinstance(self.stage, int)
                or isinstance(self.stage, bool) or self.stage < 1
                or (self.kind == FEEDFORWARD and self.stage != 1)):
            raise ConfigError(f"no controller {self.kind!r} on stage {self.stage!r}; expected "
                              f"fb_stage<i> (i >= 1) or ff_stage1")

    @classmethod
    def parse(cls, text: str) -> ControllerId:
        """The id named ``text`` (``fb_stage<i>`` or ``ff_stage1``, exactly).

        Raises
        ------
        ConfigError
            For any other string; the message quotes it and names the valid forms.
        """
        if not isinstance(text, str):
            raise ConfigError(f"unknown controller {text!r}; expected a string")
        return _parse(text)

    @classmethod
    def is_valid(cls, text: str) -> bool:
        """Whether ``text`` names a controller (:meth:`parse` accepts it)."""
        try:
            cls.parse(text)
        except ConfigError:
            return False
        return True

    def __str__(self) -> str:
        return f"{self.kind}_stage{self.stage}"

    @property
    def feedback(self) -> bool:
        """True for a feedback controller (it closes a loop around its own stage)."""
        return self.kind == FEEDBACK

    @property
    def sensed_body(self) -> int:
        """Index of the body whose velocity it reads: 0 (the ground) for feedforward, its own
        stage for feedback (bodies in cascade order, ``topics.body_names``)."""
        return self.stage if self.feedback else 0

    @property
    def frame(self) -> str:
        """Frame of the wrench it outputs: the stage it pushes, ``stage<i>``."""
        return f"stage{self.stage}"


@functools.lru_cache(maxsize=256)
def _parse(text: str) -> ControllerId:
    # cached: the plant parses the id of every force it sums, at every sample
    m = _ID.fullmatch(text)
    if m is None or (m.group(1) == FEEDFORWARD and m.group(2) != "1"):
        raise ConfigError(f"unknown controller {text!r}; expected fb_stage<i> (i >= 1) "
                          f"or ff_stage1")
    return ControllerId(m.group(1), int(m.group(2)))


#: Controller ids, also the ROS node names of the controller instances.
FB_STAGE1 = str(ControllerId(FEEDBACK, 1))
FB_STAGE2 = str(ControllerId(FEEDBACK, 2))
FF_STAGE1 = str(ControllerId(FEEDFORWARD, 1))
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


def feedback_ids(num_stages: int) -> tuple[str, ...]:
    """The feedback controllers of an N-stage cascade: ``fb_stage1`` … ``fb_stageN``."""
    return tuple(str(ControllerId(FEEDBACK, i)) for i in range(1, num_stages + 1))


def controller_ids(num_stages: int) -> tuple[str, ...]:
    """Every controller of an N-stage cascade: ``fb_stage1`` … ``fb_stageN``, then ``ff_stage1``
    (sorted as :class:`ControllerId` sorts)."""
    return (*feedback_ids(num_stages), FF_STAGE1)


def enabled_controllers(mode: Mode, num_stages: int) -> frozenset[str]:
    """Controllers a mode enables in an N-stage cascade.

    The paper's DFBC feeds back every table it has actuators under, so with N stages the dual
    (D) modes enable ``fb_stage1`` … ``fb_stageN``; single-stage modes use stage 1 only.
    """
    ids = set(mode.controllers)
    if FB_STAGE2 in ids:
        ids.discard(FB_STAGE2)
        ids.update(feedback_ids(num_stages))
    return frozenset(ids)
