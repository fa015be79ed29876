"""Crash drill of the DDS layer: node sets started at once, nodes killed with -9 while busy, new nodes after.

What a cell meets when a node crashes and is restarted, and what made Fast
DDS's shared memory hang (a participant killed while it holds, or races
for, a port's lock): ``sets`` sets of the four nodes start at the same
moment, each set in its own namespace; in every round one node of each set
is killed with SIGKILL while it is busy (its CPU time seen rising: starting
up, loading the default blisk, preparing the geometry it received), the
killed ones are started again all at once, and so on; at the end a brand
new set is started. Every node alive at the end, the new set included, must
answer a request over DDS within ``deadline`` seconds; a node that does not
is reported with its Python stacks (``SIGUSR1``: faulthandler in
:func:`edm_planner.ros.runtime.spin_node`) and the tail of its log.

``python -m edm_planner.nodes.programs.crash_drill --dds loopback-udp|stock``: the
measurement behind ``config/dds/fastdds_loopback_udp.xml`` (``stock`` runs
rmw_fastrtps's own LOCALHOST set-up, shared memory included); JSON on stdout.
``test/reliability/test_crash_drill.py`` runs it on the project's set-up.
"""

import argparse
import ipaddress
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

from ...environment import configure_process

# this entry point's set-up, before numpy loads OpenBLAS and the core's kernel modules load (both read it)
configure_process()

import rclpy
from edm_planner_msgs.srv import CheckInterference, ExecutePlan, LoadGeometry, PlanChannel
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor

from ...quick_exit import interrupt_outside_imports
from ...ros.shared import config_directory
from ...ros import dds

NODES = ("geometry_loader", "interference_checker", "trajectory_planner", "axis_bridge")
CLK_TCK = os.sysconf("SC_CLK_TCK")
UNKNOWN = "f" * 64


def cpu_seconds(pid):
    """User + system CPU time of a live process [s] (None once it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


class NodeSet:
    """The four nodes as processes in namespace ``/<name>``; logs in ``log_dir``."""

    def __init__(self, name, log_dir, field_cache, store):
        self.name, self.log_dir = name, pathlib.Path(log_dir)
        self.params = {
            "interference_checker": {"cache_dir": field_cache},
            "trajectory_planner": {"plan_store": store, "cache_dir": field_cache, "unknown_geometry_wait": 1.0},
            "axis_bridge": {"plan_store": store, "joint_states_topic": "''", "plan_wait": 1.0},
        }
        self.procs = {}

    def start(self, node):
        cmd = [os.path.join(sys.prefix, "bin", node), "--ros-args", "-r", f"__ns:=/{self.name}"]
        for k, v in self.params.get(node, {}).items():
            cmd += ["-p", f"{k}:={v}"]
        log = open(self.log_dir / f"{self.name}.{node}.log", "a")
        self.procs[node] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
        log.close()

    def kill9(self, node):
        proc = self.procs.pop(node)
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=30)

    def stop(self):
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.procs.values():
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        self.procs = {}

    def stacks(self, node, wait=2.0):
        """The node's Python stacks (faulthandler on SIGUSR1) and the end of its log."""
        proc = self.procs.get(node)
        if proc is not None and proc.poll() is None:
            os.kill(proc.pid, signal.SIGUSR1)
            time.sleep(wait)
        text = (self.log_dir / f"{self.name}.{node}.log").read_text(errors="replace")
        return text[-6000:]


def udp_local_addresses(pid):
    """The local IPv4/IPv6 addresses of the UDP sockets a process holds (``/proc/<pid>/fd`` against ``net/udp*``)."""

    inodes = set()
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    except OSError:
        return set()
    found = set()
    for table, width in (("udp", 4), ("udp6", 16)):
        try:
            with open(f"/proc/{pid}/net/{table}") as f:
                rows = f.read().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            if cols[9] in inodes:
                raw = bytes.fromhex(cols[1].split(":")[0])
                # the kernel prints each 32-bit word in host (little-endian) order
                raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
                found.add(str(ipaddress.ip_address(raw if width == 16 else raw[:4])))
    return found


def _probes():
    """Per node: (service type, service name, a request it answers at once whatever it holds)."""

    return {"geometry_loader": (LoadGeometry, "load_geometry", LoadGeometry.Request(path="default_blisk.yaml")),
            "interference_checker": (CheckInterference, "check_interference",
                                     CheckInterference.Request(geometry_id=UNKNOWN)),
            "trajectory_planner": (PlanChannel, "plan_channel", PlanChannel.Request(geometry_id=UNKNOWN)),
            "axis_bridge": (ExecutePlan, "execute_plan", ExecutePlan.Request(plan_id="no-such-plan"))}


class Prober:
    """A client node of our own (its own context, executor thread) that asks the sets' nodes."""

    def __init__(self):
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("crash_drill", context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=2, context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        self.probes = _probes()
        self.clients = {}

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:                       # shut down while spinning
            pass

    def client(self, ns, node):
        key = (ns, node)
        if key not in self.clients:
            srv_type, name, _ = self.probes[node]
            self.clients[key] = self.node.create_client(srv_type, f"/{ns}/{name}")
        return self.clients[key]

    def send(self, ns, node, request=None):
        """Send the node's probe (or ``request``); a future."""
        return self.client(ns, node).call_async(request if request is not None else self.probes[node][2])

    def close(self):
        self.executor.shutdown(timeout_sec=5.0)
        self.thread.join(timeout=5.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def wait_busy(pid, cpu=0.3, timeout=120.0):
    """Wait until the process has used ``cpu`` more seconds of CPU (it is working); False if it ended or timed out."""
    start, deadline = cpu_seconds(pid), time.monotonic() + timeout
    while True:
        now = cpu_seconds(pid)
        if start is None or now is None or time.monotonic() > deadline:
            return False
        if now - start >= cpu:
            return True
        time.sleep(0.005)


def answered_all(prober, targets, deadline_s, resend_s=5.0):
    """Send every target (ns, node) its probe; the ones not answered within ``deadline_s``, and the seconds each took.

    A node is answered when a response came back, whatever its error code. A killed server stays in the ROS
    graph until its DDS lease runs out, and a request sent meanwhile may reach only the dead one: so a probe
    not answered within ``resend_s`` is sent again.
    """
    t0 = time.monotonic()
    pending, sent, seconds = set(targets), {}, {}
    while pending and time.monotonic() - t0 < deadline_s:
        for target in list(pending):
            futures = sent.setdefault(target, [])
            if any(f.done() for f, _ in futures):
                pending.discard(target)
                seconds[target] = time.monotonic() - t0
            elif prober.client(*target).service_is_ready() and (
                    not futures or time.monotonic() - futures[-1][1] > resend_s):
                futures.append((prober.send(*target), time.monotonic()))
        time.sleep(0.02)
    return pending, seconds


def run(sets=4, rounds=2, deadline=180.0, log_dir=None, field_cache=None, progress=print):
    """The drill; a dict of what happened (``hung``: the nodes that did not answer, with their stacks).

    In round ``r`` set ``k`` loses node ``(k + r) % 4``, killed while busy: the geometry_loader while it
    loads a blisk it has not seen (a new copy of the default blisk; killed once its CPU time rose by 0.03 to
    0.09 s and before its answer came back), the other three while they start up
    (a new process of the node, killed once its CPU time rose by 0.2 to 0.8 s, a different moment for
    each: imports, the DDS participant, the latched geometry). The killed nodes are started again all at once.

    Parameters
    ----------
    sets, rounds : int
        Node sets started at once; kill-and-restart rounds.
    deadline : float
        Seconds within which every node alive at the end must answer [s].
    """

    work = pathlib.Path(log_dir or tempfile.mkdtemp(prefix="crash_drill_"))
    work.mkdir(parents=True, exist_ok=True)
    cache = field_cache or str(work / "field_cache")
    node_sets = [NodeSet(f"drill_s{k}", work, cache, str(work / f"store{k}")) for k in range(sets + 1)]
    for s in node_sets:
        s.params["geometry_loader"] = {"allowed_directories": f"[{config_directory()},{work}]"}
    fresh = node_sets.pop()                                  # started at the end
    report = {"sets": sets, "rounds": rounds, "deadline_s": deadline,
              "dds": {v: os.environ.get(v, "") for v in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE")},
              "kills": [], "hung": {}, "answer_s": {}, "log_dir": str(work)}
    prober = Prober()
    t_start = time.monotonic()

    def kill_busy(s, node, r, k):
        spread = (7 * k + 3 * r) % 4                 # a different moment for each kill
        load = None
        if node == "geometry_loader":
            copy = work / f"round{r}_{s.name}"
            copy.mkdir(exist_ok=True)
            shutil.copy(config_directory() / "default_blisk.yaml", copy)
            answered_all(prober, [(s.name, node)], deadline)            # up, so that the load reaches it
            load = prober.send(s.name, node, LoadGeometry.Request(path=str(copy / "default_blisk.yaml")))
            # a load takes about 0.25 s of CPU: killed 0.03 .. 0.09 s into it
            cpu = 0.03 + spread * 0.02
            how = "loading a blisk"
        else:
            s.kill9(node)
            s.start(node)
            # 0.2 .. 0.8 s of CPU into the start-up (the lightest node, the bridge, starts in about 1 s): imports,
            # the DDS participant, the latched geometry
            cpu = 0.2 + spread * 0.2
            how = "starting up"
        busy = wait_busy(s.procs[node].pid, cpu)
        s.kill9(node)
        if load is not None:
            # busy means the load was under way: killed before its answer came back (an idle loader's DDS
            # threads also gather CPU time, slowly)
            busy = busy and not load.done()
        report["kills"].append({"round": r, "node": f"{s.name}/{node}", "while": how, "busy_seen": busy,
                                "after_s": round(time.monotonic() - t_start, 2)})

    try:
        for s in node_sets:                                     # all at once
            for node in NODES:
                s.start(node)
        progress(f"crash drill: {4 * sets} nodes started at once")
        for r in range(rounds):
            victims = [(s, NODES[(k + r) % len(NODES)]) for k, s in enumerate(node_sets)]
            threads = [threading.Thread(target=kill_busy, args=(s, node, r, k)) for k, (s, node) in enumerate(victims)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            progress(f"crash drill: round {r + 1}: killed {', '.join(f'{s.name}/{n}' for s, n in victims)} "
                     f"while busy; starting them again at once")
            for s, node in victims:
                s.start(node)
        node_sets.append(fresh)
        for node in NODES:
            fresh.start(node)
        progress(f"crash drill: a new set started; every node must answer within {deadline:g} s")
        targets = [(s.name, n) for s in node_sets for n in s.procs]
        hung, seconds = answered_all(prober, targets, deadline)
        report["answer_s"] = {f"{ns}/{n}": round(t, 2) for (ns, n), t in seconds.items()}
        by_name = {s.name: s for s in node_sets}
        for ns, n in sorted(hung):
            report["hung"][f"{ns}/{n}"] = by_name[ns].stacks(n)
        report["dead"] = {f"{s.name}/{n}": p.returncode for s in node_sets for n, p in s.procs.items()
                          if p.poll() is not None}
        report["udp_bound_to"] = sorted(set().union(*(udp_local_addresses(p.pid) for s in node_sets
                                                       for p in s.procs.values())))
    finally:
        prober.close()
        for s in node_sets + [fresh]:
            s.stop()
    report["seconds"] = round(time.monotonic() - t_start, 1)
    return report


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dds", choices=("loopback-udp", "stock"), default="loopback-udp",
                   help="stock: rmw_fastrtps's LOCALHOST set-up (shared memory + UDP)")
    p.add_argument("--sets", type=int, default=4)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--deadline", type=float, default=180.0, metavar="S")
    p.add_argument("--log-dir", default=None)
    p.add_argument("--field-cache", default=None)
    args = p.parse_args(argv)
    # killed (SIGTERM) or interrupted, the drill still stops every node it started (run()'s finally)
    interrupt_outside_imports(signal.SIGTERM)

    setup = dds.loopback_unless_told()
    if args.dds == "stock":
        # undo what importing edm_planner.nodes did (before any rclpy.init): this process and its children on
        # rmw_fastrtps's own LOCALHOST set-up
        for variable in dds.PROFILE_VARIABLES:
            os.environ.pop(variable, None)
        os.environ.update(EDM_PLANNER_DDS="stock", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(180 + os.getpid() % 40))

    report = run(args.sets, args.rounds, args.deadline, args.log_dir, args.field_cache,
                 progress=lambda m: print(m, file=sys.stderr, flush=True))
    report["dds_setup"] = "stock" if args.dds == "stock" else setup
    sys.stdout.write(json.dumps(report, indent=1) + "\n")     # the report: JSON on stdout
    return 1 if report["hung"] else 0


if __name__ == "__main__":
    sys.exit(main())
