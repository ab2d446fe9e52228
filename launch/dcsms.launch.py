"""Launch the dcsms_ros node graph on a real ROS 2 install (``ros2 launch dcsms_ros
dcsms.launch.py``): the graph of :func:`dcsms_ros.graph.define_graph`, the same nodes, names and
parameter file that ``dcsms up`` starts, for any number of stages and either fidelity.

Arguments: ``config`` (params file, default the packaged ``config/table1.yaml``), ``schedule``
(``realtime`` | ``lockstep``), ``mode`` (initial mode, e.g. ``dfbc_ffc``), ``duration_s``
(simulated seconds, 0 = until stopped), ``namespace`` (default ``/dcsms``: two tables side by
side take two namespaces), ``composed`` (``true``: every node in one process, one driver thread
for the per-sample cycle), ``rt_priority`` (SCHED_FIFO priority 1-99 of the control path,
composed: of the driver thread; 0 = default scheduler), ``rt_cpus`` (the CPUs of those
threads, as ``taskset -c`` takes them, e.g. ``1``; empty = the kernel places them),
``excite`` (comma-separated excitation specifications, e.g. ``stage1.z:white:5``; empty = no
excitation node) and ``excite_active`` (start it with the run), as ``dcsms up``.
"""

import os
import sys
import tempfile

import yaml
from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import parse_mode
from dcsms_ros.graph import RT_CPUS_ENV, RT_PRIORITY_ENV, define_graph
from launch import LaunchDescription

PACKAGE = "dcsms_ros"


def _nodes(context, *args, **kwargs):
    arg = {name: LaunchConfiguration(name).perform(context) for name in (
        "config", "schedule", "mode", "duration_s", "namespace", "composed", "rt_priority",
        "rt_cpus", "excite", "excite_active")}
    spec = define_graph(load_config(arg["config"]), schedule=arg["schedule"],
                        mode=parse_mode(arg["mode"]), namespace=arg["namespace"],
                        duration_s=float(arg["duration_s"]),
                        excite=[s.strip() for s in arg["excite"].split(",") if s.strip()],
                        excite_active=arg["excite_active"].lower() in ("true", "1", "yes"))
    run_dir = tempfile.mkdtemp(prefix="dcsms-launch-")
    params = os.path.join(run_dir, "params.yaml")
    with open(params, "w") as f:
        yaml.safe_dump(spec.params_document(), f, sort_keys=False)
    # read by dcsms_ros.ros.runtime: the hot thread alone runs under SCHED_FIFO, on rt_cpus
    rt = {RT_PRIORITY_ENV: arg["rt_priority"], RT_CPUS_ENV: arg["rt_cpus"]}
    if arg["composed"].lower() in ("true", "1", "yes"):
        graph = os.path.join(run_dir, "graph.yaml")
        with open(graph, "w") as f:
            yaml.safe_dump(spec.to_dict(), f, sort_keys=False)
        return [ExecuteProcess(cmd=[sys.executable, "-m", "dcsms_ros.nodes.container",
                                    "--graph", graph, "--params-file", params,
                                    "--rt-priority", arg["rt_priority"]],
                              additional_env={RT_CPUS_ENV: arg["rt_cpus"]}, output="screen")]
    return [Node(package=PACKAGE, executable=n.executable, name=n.name,
                 namespace=spec.namespace, parameters=[params], remappings=list(n.remappings),
                 output="screen", additional_env=rt if n.control_path else {})
            for n in spec.nodes]


def generate_launch_description():
    """Declare the arguments and start the graph."""
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
        DeclareLaunchArgument("namespace", default_value="/dcsms",
                              description="namespace of every topic and service of the graph"),
        DeclareLaunchArgument("composed", default_value="false",
                              description="true: every node in one process"),
        DeclareLaunchArgument("rt_priority", default_value="0",
                              description="SCHED_FIFO priority 1-99 of the control path "
                              "(needs CAP_SYS_NICE); 0 = default scheduler"),
        DeclareLaunchArgument("rt_cpus", default_value="",
                              description="CPUs of the control path's hot threads (e.g. 1 or "
                              "0,2-3); empty = the kernel places them"),
        DeclareLaunchArgument("excite", default_value="",
                              description="excitation specifications, comma-separated (e.g. "
                              "stage1.z:white:5); empty = no excitation node"),
        DeclareLaunchArgument("excite_active", default_value="true",
                              description="start the excitation with the run (else "
                              "<namespace>/excitation/enable starts it)"),
        OpaqueFunction(function=_nodes),
    ])
