"""Launch the dcsms_ros node graph on a real ROS 2 install (``ros2 launch dcsms_ros
dcsms.launch.py``): the same nodes, names and parameter file that ``dcsms up`` starts.

Arguments: ``config`` (params file, default the packaged ``config/table1.yaml``), ``schedule``
(``realtime`` | ``lockstep``), ``mode`` (initial mode, e.g. ``dfbc_ffc``), ``duration_s``
(simulated seconds, 0 = until stopped), ``rt_priority`` (SCHED_FIFO priority 1-99 of the
control path: plant, decoupling, controllers; 0 = default scheduler), ``excite``
(comma-separated excitation specifications, e.g. ``stage1.z:white:5``; empty = no excitation
node) and ``excite_active`` (start it active), as ``dcsms up``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "dcsms_ros"
NAMESPACE = "/dcsms"
NUM_STAGES = 2
#: Controllers each mode enables (dcsms_ros.core.modes, for the paper's two stages).
ENABLED = {
    "passive": (),
    "fbc": ("fb_stage1",),
    "ffc": ("ff_stage1",),
    "fbc_ffc": ("fb_stage1", "ff_stage1"),
    "dfbc": ("fb_stage1", "fb_stage2"),
    "dfbc_ffc": ("fb_stage1", "fb_stage2", "ff_stage1"),
}


def _nodes(context, *args, **kwargs):
    config = LaunchConfiguration("config").perform(context)
    schedule = LaunchConfiguration("schedule").perform(context)
    mode = LaunchConfiguration("mode").perform(context).lower().replace("+", "_")
    duration = float(LaunchConfiguration("duration_s").perform(context))
    on = ENABLED[mode]
    common = {"schedule": schedule}
    sim = {"use_sim_time": True}
    # read by dcsms_ros.nodes.runtime before rclpy starts (every thread inherits it)
    rt = {"DCSMS_RT_PRIORITY": LaunchConfiguration("rt_priority").perform(context)}
    nodes = [
        Node(package=PACKAGE, executable="plant_simulator", name="plant_simulator",
             namespace=NAMESPACE, parameters=[config, common, {"duration_s": duration}],
             output="screen", additional_env=rt),
        Node(package=PACKAGE, executable="sensor_decoupling", name="sensor_decoupling",
             namespace=NAMESPACE, parameters=[config, common, sim], output="screen",
             additional_env=rt),
        Node(package=PACKAGE, executable="mode_switch", name="mode_switch",
             namespace=NAMESPACE, parameters=[config, common, {"initial_mode": mode}],
             output="screen"),
        Node(package=PACKAGE, executable="feedforward_controller", name="ff_stage1",
             namespace=NAMESPACE,
             parameters=[config, common, sim, {"enabled": "ff_stage1" in on}], output="screen",
             additional_env=rt),
    ]
    for i in range(1, NUM_STAGES + 1):
        cid = f"fb_stage{i}"
        nodes.append(Node(package=PACKAGE, executable="feedback_controller", name=cid,
                          namespace=NAMESPACE,
                          parameters=[config, common, sim, {"stage": i, "enabled": cid in on}],
                          output="screen", additional_env=rt))
    excite = [s.strip() for s in LaunchConfiguration("excite").perform(context).split(",")
              if s.strip()]
    if excite:  # the excitation node, summed by the plant (its `excitation` parameter)
        active = LaunchConfiguration("excite_active").perform(context).lower() == "true"
        nodes[0] = Node(package=PACKAGE, executable="plant_simulator", name="plant_simulator",
                        namespace=NAMESPACE, parameters=[config, common, {
                            "duration_s": duration, "excitation": True}],
                        output="screen", additional_env=rt)
        nodes.append(Node(package=PACKAGE, executable="excitation", name="excitation",
                          namespace=NAMESPACE, parameters=[config, common, sim, {
                              "spec": excite, "active": active, "duration_s": duration}],
                          output="screen", additional_env=rt))
    return nodes


def generate_launch_description():
    """Declare the arguments and start the six nodes."""
    share = get_package_share_directory(PACKAGE)
    return LaunchDescription([
        DeclareLaunchArgument("config", default_value=os.path.join(share, "config",
                                                                   "table1.yaml"),
                              description="ROS 2 params file of the system"),
        DeclareLaunchArgument("schedule", default_value="realtime",
                              description="realtime or lockstep"),
        DeclareLaunchArgument("mode", default_value="passive",
                              description="initial mode: passive fbc ffc fbc_ffc dfbc dfbc_ffc"),
        DeclareLaunchArgument("duration_s", default_value="0.0",
                              description="simulated seconds to run; 0 = until stopped"),
        DeclareLaunchArgument("rt_priority", default_value="0",
                              description="SCHED_FIFO priority 1-99 of the control path "
                              "(needs CAP_SYS_NICE); 0 = default scheduler"),
        DeclareLaunchArgument("excite", default_value="",
                              description="excitation specifications, comma-separated (e.g. "
                              "stage1.z:white:5); empty = no excitation node"),
        DeclareLaunchArgument("excite_active", default_value="true",
                              description="start the excitation with the run (else "
                              "/dcsms/excitation/enable starts it)"),
        OpaqueFunction(function=_nodes),
    ])
