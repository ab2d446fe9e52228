"""Feedforward controller node ``ff_stage1``: ground velocity into the stage-1 actuators.

Reads ``/dcsms/velocity/ground``, publishes ``/dcsms/force/ff_stage1`` (frame ``stage1``) and
offers ``/dcsms/ff_stage1/enable``; tuning ``feedforward.*``, with the stage-1 suspension
(``stage1.damping``/``stiffness`` or the 6-DOF mounts) for the ideal ``c1 + k1/s``.
"""

from __future__ import annotations

from typing import Any

from dcsms_ros.core import topics
from dcsms_ros.core.modes import FF_STAGE1
from dcsms_ros.nodes import recorder_part
from dcsms_ros.ros.controller_node import ControllerNode
from dcsms_ros.ros.params import SELECTORS
from dcsms_ros.ros.runtime import main_for


class FeedforwardControllerNode(ControllerNode):
    """ROS adapter around :class:`~dcsms_ros.core.controllers.FeedforwardLoop`."""

    def __init__(self, node_name: str = FF_STAGE1, **kwargs: Any) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.setup(FF_STAGE1, SELECTORS["feedforward_controller"], "ground")


main = main_for(FeedforwardControllerNode, attach=recorder_part.attach)

if __name__ == "__main__":
    main()
