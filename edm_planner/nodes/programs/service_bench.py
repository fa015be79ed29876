"""``make bench``'s service round trips: the nodes in this process, a client over DDS on loopback; JSON out.

geometry_loader and interference_checker spin in this process (the loader loads its default file when it
starts and publishes it; the checker prepares it and its distance field), a client node calls them:

* ``--check-poses OFFSETS.npy``: CheckInterference (fast method) of one pose per offset, about the final pose
  of the checker's first electrode (:func:`poses_about`);
* ``--load-geometry PATH``: LoadGeometry of a file the loader has loaded already (answered from memory by
  content hash).

Every figure is the median of ``--repeat`` calls after one untimed call (numba's first call, DDS discovery
and the first reply's allocations are not timed). ``python -m edm_planner.nodes.programs.service_bench``
prints one JSON object on stdout: ``check_interference_ms`` and ``check_interference_poses``,
``load_geometry_ms``, each only when asked for. The bench (:mod:`edm_planner.bench.service`, which imports
no ROS) runs it as a child process with a deadline; DDS stays on this machine unless the caller chose a
range (:func:`edm_planner.ros.dds.loopback_unless_told`).
"""

import argparse
import contextlib
import json
import os
import sys
import threading
import time

from ...environment import configure_process

# this entry point's set-up, before numpy loads OpenBLAS and the core's kernel modules load (both read it)
configure_process()

import numpy as np
import rclpy
from edm_planner_msgs.srv import CheckInterference, LoadGeometry
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from ...ros.conversions import matrices_to_poses
from ...ros.dds import loopback_unless_told
from ...ros.runtime import enable_stack_dumps
from ..geometry_loader import GeometryLoaderNode
from ..interference_checker import InterferenceCheckerNode

#: how long the checker may take to receive and prepare the loader's geometry [s]
GEOMETRY_WAIT_S = 120


@contextlib.contextmanager
def nodes_in_process():
    """geometry_loader and interference_checker spinning in this process, and a client node.

    Yields (loader, checker, client) once the checker holds the loader's geometry. Call
    :func:`~edm_planner.ros.dds.loopback_unless_told` before (``main`` does).
    """

    ctx = Context()
    rclpy.init(context=ctx)
    ex = MultiThreadedExecutor(context=ctx)
    loader = GeometryLoaderNode(context=ctx)
    checker = InterferenceCheckerNode(context=ctx)
    client = Node("bench_client", context=ctx)
    for node in (loader, checker, client):
        ex.add_node(node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    try:
        deadline = time.monotonic() + GEOMETRY_WAIT_S
        while not checker.received.items and time.monotonic() < deadline:
            time.sleep(0.1)
        if not checker.received.items:
            raise RuntimeError(f"the interference_checker received no geometry within {GEOMETRY_WAIT_S} s")
        yield loader, checker, client
    finally:
        ex.shutdown()
        th.join(timeout=10)                  # the spinning thread ended before the nodes go (the process exits next)
        for node in (loader, checker, client):
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _median_call_ms(client, srv_type, name, request, repeat):
    """Median wall time [ms] of ``repeat`` calls after one untimed call; the last response."""
    cli = client.create_client(srv_type, name)
    if not cli.wait_for_service(timeout_sec=30):
        raise RuntimeError(f"service {name} not available")

    def call():
        fut = cli.call_async(request)
        while not fut.done():
            time.sleep(0.0005)
        return fut.result()

    call()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        response = call()
        times.append(time.perf_counter() - t)
    return round(1e3 * float(np.median(times)), 1), response


def poses_about(final_pose, offsets):
    """Poses near ``final_pose``: each offset's rotation before the final pose's, its translation added.

    ``offsets`` are poses near the identity (the bench's ``poses_near(np.eye(4), n)``); the result is then
    bit for bit ``poses_near(final_pose, n)`` with the same seed and spread.
    """
    final, offsets = np.asarray(final_pose, dtype=float), np.asarray(offsets, dtype=float)
    poses = np.repeat(final[None], len(offsets), axis=0)
    poses[:, :3, :3] = offsets[:, :3, :3] @ final[:3, :3]
    poses[:, :3, 3] += offsets[:, :3, 3]
    return poses


def check_interference_round_trip(nodes, offsets, repeat=7):
    """Median round trip [ms] of CheckInterference (fast method) of the poses ``offsets`` make of the checker's
    first electrode's final pose (:func:`poses_about`)."""
    _, checker, client = nodes
    gid, ch = next(iter(checker.received.items.items()))
    ch.fast                                                  # field built before timing
    final = next(iter(ch.electrodes.values()))[1]
    req = CheckInterference.Request(geometry_id=gid, method=CheckInterference.Request.METHOD_FAST)
    req.poses = matrices_to_poses(poses_about(final, offsets))
    ms, response = _median_call_ms(client, CheckInterference, "check_interference", req, repeat)
    if response.error_code.val != 0 or len(response.clearances) != len(offsets):
        raise RuntimeError(f"CheckInterference failed: {response.message}")
    return ms


def load_geometry_round_trip(nodes, path, repeat=7):
    """Median round trip [ms] of LoadGeometry of a file the geometry_loader has loaded already.

    The node loads its default file when it starts; the timed calls name the same unchanged file, which it
    answers from memory by content hash.
    """
    _, _, client = nodes
    ms, response = _median_call_ms(client, LoadGeometry, "load_geometry", LoadGeometry.Request(path=str(path)),
                                   repeat)
    if not response.success:
        raise RuntimeError(f"LoadGeometry failed: {response.message}")
    return ms


def run(offsets=None, load_geometry=None, repeat=7):
    """The asked round trips on one bring-up of the nodes; a dict of figures (see the module's docstring)."""
    out = {}
    with nodes_in_process() as nodes:
        if offsets is not None:
            out["check_interference_ms"] = check_interference_round_trip(nodes, offsets, repeat)
            out["check_interference_poses"] = len(offsets)
        if load_geometry is not None:
            out["load_geometry_ms"] = load_geometry_round_trip(nodes, load_geometry, repeat)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description="Service round trips over DDS, nodes in this process (JSON out).")
    parser.add_argument("--check-poses", metavar="OFFSETS.npy",
                        help="time CheckInterference of these pose offsets (n x 4 x 4) about the final pose")
    parser.add_argument("--load-geometry", metavar="PATH",
                        help="time LoadGeometry of this file (one the loader loaded at start)")
    parser.add_argument("--repeat", type=int, default=7, help="timed calls per service (after one untimed)")
    args = parser.parse_args(argv)
    enable_stack_dumps()                       # kill -USR1: every thread's stack on stderr (the bench's deadline)
    loopback_unless_told()
    os.environ.setdefault("ROS_DOMAIN_ID", str(101 - os.getpid() % 50))
    offsets = np.load(args.check_poses) if args.check_poses else None
    result = run(offsets, args.load_geometry, args.repeat)
    sys.stdout.write(json.dumps(result) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
