"""Composed deployment: every node of a graph in one process, one driver thread for the cycle.

``python -m dcsms_ros.nodes.container --graph GRAPH.yaml --params-file PARAMS.yaml`` (what
``dcsms up --composed`` and the launch argument ``composed:=true`` run) creates each node of the
graph (:mod:`dcsms_ros.graph`) with its own class, name, parameters and services, all on one
rclpy context. The node classes are the ones of the one-process-per-node deployment; what
changes is who serves their per-sample subscriptions: one
:class:`~dcsms_ros.ros.hotpath.HotLoop`, the *driver*, serves every node's hot path in one
thread (the nodes live on a
:class:`~dcsms_ros.ros.hotpath.DrivenContext`, which holds it). In lockstep the
plant publishes sample k, the decoupling takes it and answers, each controller takes that
answer and answers in turn, and the plant takes the forces and publishes k+1 - every hop
handed over in the process (the context's bus, :mod:`dcsms_ros.ros.intraprocess`), and
published on DDS too while a subscriber in another process (a recorder, ``ros2 topic echo``)
is matched, so it sees every message. In real time the plant's pacer runs the same cycle at
its deadlines. Services, parameters, timers, ``/clock`` and the mode switch stay on one
single-threaded executor (the mode switch awaits its service calls as tasks); each node's
callbacks there run under its hot-path lock (:mod:`dcsms_ros.ros.serialized`), one at a time
with its handlers on the driver thread. Not rclpy's multi-threaded executor: in rclpy 7.1.6 it
hands a callback to a worker and rebuilds its wait set over every entity of the process again
before that worker has started (rclpy PR 1547), and its worker threads compete with the driver
for the GIL. Measured composed, recorded, real time at SCHED_FIFO 50 (docs/performance.md):
the executor's threads used 37-38 % of a core with three workers, 26-31 % as one thread.

The executor is :class:`~dcsms_ros.ros.executor.HostExecutor` (no wake-up after every
callback), the nodes' periodic jobs run from one timer
(:class:`~dcsms_ros.ros.housekeeping.Housekeeper`), and the start-up heap is frozen before the
driver starts (:func:`~dcsms_ros.ros.hotloop.settle_heap`).

``--rt-priority N`` puts the driver thread (only it) under SCHED_FIFO and, in real time, the
executor's thread on the driver's core, where it runs only while the driver waits
(:mod:`dcsms_ros.ros.hotloop`); ``$DCSMS_RT_CPUS`` (``dcsms up --rt-cpus``) the CPUs of the
driver, the executor's thread then on the last of them. ``--record OUT
[TOPIC ...]`` runs the recorder node in this process too (``dcsms up --recorder composed``):
it takes the graph's messages from the bus, every one of them, in lockstep and in real time,
and a bag writer process it starts writes the bag (:mod:`dcsms_ros.analysis.bagprocess`).
Exit status: 0 after SIGINT/SIGTERM or a finished run, 2 after a configuration error (one line).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from rclpy.context import Context
from rclpy.node import Node

from dcsms_ros.errors import DcsmsError
from dcsms_ros.graph import LOCKSTEP_WRITER_DEPTH, GraphSpec, NodeSpec, spec_from_dict
from dcsms_ros.nodes.plant_simulator import PlantSimulatorNode
from dcsms_ros.nodes.recorder import Recorder
from dcsms_ros.ros.context import STOP_EXCEPTIONS, ros_context, spin_until
from dcsms_ros.ros.executor import HostExecutor
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hotloop import settle_heap
from dcsms_ros.ros.hotpath import DrivenContext
from dcsms_ros.ros.housekeeping import Housekeeper
from dcsms_ros.ros.runtime import close_nodes, config_error, quiesce, report_hold, rt_cpus_from_env
from dcsms_ros.ros.serialized import Serialized, serialize


def node_class(spec: NodeSpec) -> Any:
    """The class of a node (``module:Class`` of :data:`dcsms_ros.graph.NODE_CLASSES`)."""
    module, _, cls = spec.node_class.partition(":")
    return getattr(importlib.import_module(module), cls)


def create_nodes(spec: GraphSpec, ctx: Context) -> list[Node]:
    """Every node of ``spec`` on ``ctx``, in the spec's order (parameters come from the
    context's ``--params-file``, by each node's full name)."""
    nodes = []
    for n in spec.nodes:
        remap = [a for f, t in n.remappings for a in ("-r", f"{f}:={t}")]
        nodes.append(node_class(n)(node_name=n.name, namespace=spec.namespace, context=ctx,
                                   cli_args=["--ros-args", *remap] if remap else None))
    return nodes


def run(graph_file: Path, params_file: Path, rt_priority: int = 0,
        record: Sequence[str] = ()) -> int:
    """Run the composed graph until a signal or the plant's end; see the module notes."""
    spec = spec_from_dict(yaml.safe_load(graph_file.read_text()))
    status = 0
    ctx = DrivenContext("driver")
    loop = ctx.driver
    loop.cpus, cpus_warning = rt_cpus_from_env()
    if spec.schedule == "lockstep":
        # a lockstep driver never waits for a deadline: on its core the executor would get
        # only what the kernel's real-time throttling leaves (the mode switches, the flush)
        loop.share_core_with = None
    with ros_context(["--ros-args", "--params-file", str(params_file)], signals=True,
                     context=ctx) as ros:
        nodes: list[Node] = []
        serials: list[Serialized | None] = []
        recorder: Any = None
        executor = HostExecutor(context=ctx)
        keeper = Housekeeper(executor)  # every node's periodic jobs on one timer
        try:
            if record:
                lockstep = spec.schedule == "lockstep"
                recorder = Recorder(record[0], list(record[1:]) or None, context=ctx,
                                    queue_depth=LOCKSTEP_WRITER_DEPTH if lockstep else None,
                                    lossless=lockstep,
                                    writer_cpus=loop.spare_cpus(rt_priority))
                executor.add_node(recorder)
            nodes = create_nodes(spec, ctx)
            serials = [serialize(nd) for nd in nodes]  # before any callback can run
            keeper.keep(*(nd.jobs for nd in [recorder, *nodes] if isinstance(nd, GraphNode)))
            for nd in nodes:
                executor.add_node(nd)
            if recorder is not None:  # the in-process topics from their first message on
                recorder.discover()
            settle_heap()
            loop.start(rt_priority)
            for warning in (cpus_warning, loop.rt_warning):
                if warning:
                    nodes[-1].get_logger().warning(warning)
            plant = next((nd for nd in nodes if isinstance(nd, PlantSimulatorNode)), None)

            def done() -> bool:
                if loop.error is not None:
                    raise loop.error
                return bool(ros.stop) or (plant is not None and plant.finished)

            spin_until(executor, done)
        except DcsmsError as exc:
            status = config_error(exc)
        except STOP_EXCEPTIONS:
            pass
        finally:
            loop.stop()
            keeper.stop()  # its timer lives on one node: no job of a destroyed node may run
            for nd, serial in zip(nodes, serials, strict=False):
                report_hold(nd, serial)
            since = time.time_ns()
            for nd in reversed(nodes):
                quiesce(executor, nd, timeout_s=1.0)
            # bounded once nothing is left to save: without a recorder, before the nodes go
            close_nodes(nodes[::-1], ros.bound_teardown if recorder is None else lambda: None)
            if ctx.bus is not None:  # what is still queued (final reports) to the recorder
                ctx.bus.close()
            if recorder is not None:
                recorder.drain(executor, since)
                print(recorder.finish().text(), flush=True)
                ros.bound_teardown()
                recorder.destroy_node()
            executor.shutdown(timeout_sec=2.0)
    return status


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m dcsms_ros.nodes.container --graph FILE --params-file FILE``."""
    ap = argparse.ArgumentParser(prog="dcsms_ros.nodes.container", description=__doc__.split(
        "\n\n")[0])
    ap.add_argument("--graph", type=Path, required=True, help="graph file (GraphSpec YAML)")
    ap.add_argument("--params-file", type=Path, required=True, help="ROS 2 params file")
    ap.add_argument("--rt-priority", type=int, default=0, help="SCHED_FIFO of the driver")
    ap.add_argument("--record", nargs="+", default=(), metavar="OUT [TOPIC]",
                    help="run the recorder here too: bag directory, then topics")
    a = ap.parse_args(argv)
    sys.exit(run(a.graph, a.params_file, a.rt_priority, a.record))


if __name__ == "__main__":
    main()
