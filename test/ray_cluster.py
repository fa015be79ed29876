"""A local two-node Ray cluster for the scale-out tests, and the Ray worker processes running our tasks now.

:func:`two_node_cluster` starts a Ray cluster of two nodes of one CPU each on loopback (no dashboard, its files
and token in a temporary directory), connects this process and yields (cluster, [head node, worker node]);
everything is shut down and removed after. test_ray_scaleout.py and test_blisk_plan.py make their module
fixtures of it.
"""

import contextlib
import pathlib
import shutil
import sys
import tempfile

from edm_planner.machining import executors


@contextlib.contextmanager
def two_node_cluster():
    """A Ray cluster of two nodes of one CPU each on loopback, this process connected; (cluster, nodes)."""
    temp = tempfile.mkdtemp(prefix="edm_ray_test_")
    previous = executors._loopback_environment(temp)
    imported = "ray" in sys.modules
    import ray
    from ray.cluster_utils import Cluster

    if imported:
        executors._reread_ray_configuration()
    c = None
    try:
        c = Cluster(initialize_head=True, connect=False,
                    head_node_args={"num_cpus": 1, "include_dashboard": False, "temp_dir": temp,
                                    "object_store_memory": 200 * 1024 * 1024})
        worker_node = c.add_node(num_cpus=1, object_store_memory=200 * 1024 * 1024)
        c.wait_for_nodes(timeout=60)
        ray.init(address=c.address, log_to_driver=False)
        nodes = [n["NodeID"] for n in ray.nodes() if n["Alive"]]
        assert len(nodes) == 2, ray.nodes()
        assert all(n["NodeManagerAddress"] == "127.0.0.1" for n in ray.nodes())
        yield c, [c.head_node, worker_node]
    finally:
        ray.shutdown()
        if c is not None:
            c.shutdown()
        executors._restore(previous)
        shutil.rmtree(temp, ignore_errors=True)


def task_processes(nodes):
    """(pid) of the Ray worker processes of ``nodes`` running one of our tasks (executors._edm_task) now."""
    raylets = {p.process.pid for n in nodes for p in n.all_processes.get("raylet", [])}
    out = []
    for proc in pathlib.Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmdline = (proc / "cmdline").read_bytes()
            ppid = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if ppid in raylets and cmdline.startswith(b"ray::_edm_task"):
            out.append(int(proc.name))
    return out
