"""Feedback controller node: velocity (skyhook) feedback of one stage.

One executable, one instance per stage: parameter ``stage`` (1-based) selects the stage; the
node must be named ``fb_stage<stage>`` in namespace ``/dcsms`` (``-r __node:=fb_stage2``), so
it reads ``/dcsms/velocity/stage<stage>``, publishes ``/dcsms/force/fb_stage<stage>`` and offers
``/dcsms/fb_stage<stage>/enable``. It declares only its own stage's ``feedback.stage<i>.*``
tuning plus the fade time and input timeout (and the system structure, see
:mod:`dcsms_ros.ros.params`).
"""

from __future__ import annotations

from typing import Any

from dcsms_ros.core import topics
from dcsms_ros.core.modes import FB_STAGE1, FEEDBACK, ControllerId
from dcsms_ros.nodes import recorder_part
from dcsms_ros.ros.controller_node import ControllerNode
from dcsms_ros.ros.params import declare_local, feedback_select
from dcsms_ros.ros.runtime import main_for


class FeedbackControllerNode(ControllerNode):
    """ROS adapter around :class:`~dcsms_ros.core.controllers.FeedbackLoop`."""

    def __init__(self, node_name: str = FB_STAGE1, **kwargs: Any) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__(node_name, **kwargs)
        stage = int(declare_local(self, "stage", 1, "Stage whose velocity is fed back (1-based)",
                                  lo=1, hi=8))
        cid = ControllerId(FEEDBACK, stage)
        self.setup(str(cid), feedback_select(stage), f"stage{stage}")


main = main_for(FeedbackControllerNode, attach=recorder_part.attach)

if __name__ == "__main__":
    main()
