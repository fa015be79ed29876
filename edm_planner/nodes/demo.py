"""``make demo``: the whole product once, as a cell controller drives it over DDS.

Starts the four nodes as separate processes (launch-free bring-up), then
LoadGeometry (the built-in default blisk) -> PlanChannel (channel 0) ->
ExecutePlan, with a monitor subscriber receiving the JointTrajectory; asks
the interference_checker for the clearances along the published path;
prints a summary and writes ``out/demo/``: the plan export, axis curves
against time and against the sample index (Huang Fig. 7), the clearance per
surface along the path, and the electrode's swept positions in the channel
(GLB and PNG). Every process it started is stopped, also on Ctrl-C or
failure; the exit status is non-zero if any step failed.

The default blisk's primitive electrode cannot leave its 104-degree channel
(the planner says so); the demo plans the rear electrode of a front/rear
split (h = 0.03 rad, radial reduction 3 mm), which exits downstream.
"""

import argparse
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import numpy as np

NODES = ("geometry_loader", "interference_checker", "trajectory_planner", "axis_bridge")
TRAJECTORY_TOPIC = "/edm_controller/joint_trajectory"


class Bringup:
    """The nodes as OS processes through their console entry points; logs in ``log_dir``."""

    def __init__(self, log_dir, params=None):
        self.log_dir = pathlib.Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.params = params or {}
        self.procs = {}

    def start(self, names=NODES):
        bin_dir = pathlib.Path(sys.prefix) / "bin"
        for name in names:
            cmd = [str(bin_dir / name)]
            extra = self.params.get(name, {})
            if extra:
                cmd += ["--ros-args"] + [x for k, v in extra.items() for x in ("-p", f"{k}:={v}")]
            log = open(self.log_dir / f"{name}.log", "w")
            self.procs[name] = (subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy(),
                                                 start_new_session=True), log)

    def check_alive(self):
        for name, (proc, _) in self.procs.items():
            if proc.poll() is not None:
                raise RuntimeError(f"node {name} exited with {proc.returncode}; see {self.log_dir / name}.log")

    def stop(self):
        for proc, _ in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc, log in self.procs.values():
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            log.close()
        self.procs = {}


class Step:
    """Prints a numbered step and its duration."""

    count = 0

    def __init__(self, text):
        Step.count += 1
        self.text = text

    def __enter__(self):
        print(f"[{Step.count}] {self.text} ...", flush=True)
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, kind, *rest):
        if kind is None:
            print(f"    done in {time.perf_counter() - self.t0:.1f} s", flush=True)


def _call(node, srv_type, name, request, timeout, bringup):
    client = node.create_client(srv_type, name)
    deadline = time.monotonic() + timeout
    while not client.wait_for_service(timeout_sec=0.5):
        bringup.check_alive()
        if time.monotonic() > deadline:
            raise RuntimeError(f"service {name} not available after {timeout:.0f} s")
    future = client.call_async(request)
    while not future.done():
        bringup.check_alive()
        if time.monotonic() > deadline:
            raise RuntimeError(f"service {name} did not answer within {timeout:.0f} s")
        time.sleep(0.02)
    node.destroy_client(client)
    return future.result()


def _require(response, what):
    ok = response.success if hasattr(response, "success") else response.error_code.val == 0
    if not ok:
        raise RuntimeError(f"{what} failed (error code {response.error_code.val}): {response.message}")
    return response


def run(out_dir, channel, bringup, timeout=600.0):
    import rclpy
    from edm_planner_msgs.msg import ElectrodeDesign
    from edm_planner_msgs.srv import CheckInterference, ExecutePlan, LoadGeometry, PlanChannel
    from rclpy.executors import SingleThreadedExecutor
    from trajectory_msgs.msg import JointTrajectory

    from .. import plots
    from ..geometry.loader import load_geometry
    from ..planning.export import read_plan

    share = pathlib.Path(sys.prefix) / "share" / "edm_planner" / "config"
    from rclpy.signals import SignalHandlerOptions

    # Ctrl-C must reach the demo as KeyboardInterrupt (stop the nodes, exit 130), not shut rclpy down
    # under a service call in flight (rclpy's own handler), which would read as a failed step
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("edm_demo_cell_controller")
    received = []
    got = threading.Event()
    node.create_subscription(JointTrajectory, TRAJECTORY_TOPIC, lambda m: (received.append(m), got.set()), 10)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        with Step("LoadGeometry: the built-in default blisk"):
            geo = _require(_call(node, LoadGeometry, "load_geometry",
                                 LoadGeometry.Request(path=str(share / "default_blisk.yaml")), timeout, bringup),
                           "LoadGeometry")
            s = geo.summary
            print(f"    {s.name or 'default blisk'}: {s.blade_count} blades, id {geo.geometry_id[:12]}, "
                  f"min channel width {s.min_channel_width:.3f} mm")
        with Step(f"PlanChannel: channel {channel}, rear electrode of a front/rear split"):
            nan = float("nan")
            design = ElectrodeDesign(discharge_gap=nan, circumferential_reduction=0.03, reduction_side="",
                                     radial_reduction=3.0, axial_start=nan, axial_end=nan, split="front_rear",
                                     split_fraction=nan, split_overlap=1.0)
            req = PlanChannel.Request(geometry_id=geo.geometry_id, channel=channel, electrode_id="rear",
                                      electrode=design, write_export=True)
            plan = _require(_call(node, PlanChannel, "plan_channel", req, timeout, bringup), "PlanChannel")
            m = plan.metrics
            print(f"    plan {plan.plan_id}: {plan.message}")
        with Step("ExecutePlan: time the path and send the JointTrajectory"):
            ex = _require(_call(node, ExecutePlan, "execute_plan",
                                ExecutePlan.Request(plan_id=plan.plan_id, channel=channel, dry_run=False),
                                timeout, bringup), "ExecutePlan")
            if not got.wait(30.0):
                raise RuntimeError(f"no JointTrajectory received on {TRAJECTORY_TOPIC}")
            traj = received[-1]
            print(f"    {ex.point_count} points, {ex.duration:.2f} s; monitor received "
                  f"{len(traj.points)} points for joints {list(traj.joint_names)}")
        with Step("CheckInterference: clearances along the published path (fast method)"):
            chk = CheckInterference.Request(geometry_id=geo.geometry_id, channel=channel, electrode_id="rear",
                                            electrode=design, method=CheckInterference.Request.METHOD_FAST)
            chk.poses = list(plan.poses.poses)
            clear_res = _require(_call(node, CheckInterference, "check_interference", chk, timeout, bringup),
                                 "CheckInterference")
            clear = np.array([[c.suction, c.pressure, c.hub, c.shroud] for c in clear_res.clearances])
            print(f"    {clear_res.message}; smallest {clear.min():.4f} mm (field error bound "
                  f"{clear_res.error_bound * 1e3:.1f} um)")
        with Step(f"plots and 3D view in {out_dir}"):
            export = read_plan(plan.export_path)
            t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in traj.points])
            q = np.array([p.positions for p in traj.points])
            plots.axis_curves(t, q, list(traj.joint_names), out_dir / "axes_vs_time.png", "time [s]",
                              f"Axis motion as sent to the controller ({ex.duration:.1f} s)")
            samples = np.array([p.positions for p in plan.axis_path.points])
            plots.axis_curves(np.arange(len(samples)), samples, list(plan.axis_path.axis_names),
                              out_dir / "axes_vs_index.png", "sample index (feed order)",
                              "Axis values along the certified path (cf. Huang Fig. 7)")
            g = load_geometry(share / "default_blisk.yaml")
            margins = [0.02, 0.02, 0.02, 0.02]
            plots.clearance_plot(np.arange(len(clear)), clear, margins, out_dir / "clearance.png")
            plots.channel_view(g.blisk.channel_meshes(channel, resolution=1.0), export.electrode_mesh,
                               export.poses, out_dir / "channel.glb", out_dir / "channel.png")
        print("\nSummary")
        print(f"  geometry     default blisk, id {geo.geometry_id[:12]}, channel {channel}")
        print(f"  method       default (LP), {m.node_count} nodes, {len(samples)} samples, path "
              f"{m.path_length:.1f} mm, certified {m.certified}")
        print("  min clearance [mm]  " + ", ".join(
            f"{n} {v:.4f}" for n, v in zip(("suction", "pressure", "hub", "shroud"),
                                           (m.min_clearance_suction, m.min_clearance_pressure,
                                            m.min_clearance_hub, m.min_clearance_shroud))))
        print(f"  plan time    {m.planning_time:.2f} s; trajectory {ex.duration:.2f} s, {ex.point_count} points")
        print(f"  written      {plan.export_path} (plan export), {out_dir}/*.png, {out_dir}/channel.glb")
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv=None):
    parser = argparse.ArgumentParser(description="edm_planner end-to-end demo (make demo)")
    parser.add_argument("--out", default="out/demo", help="output directory")
    parser.add_argument("--channel", type=int, default=0)
    args = parser.parse_args(argv)
    # Ctrl-C and kill stop the nodes too: raise KeyboardInterrupt here even when the demo was started
    # with SIGINT ignored (a background job of a non-interactive shell inherits SIG_IGN)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 80))
    out = pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    bringup = Bringup(out / "logs", params={"trajectory_planner": {"export_dir": str(out / "plans")}})
    status = 0
    try:
        with Step(f"starting {', '.join(NODES)} (logs in {out / 'logs'})"):
            bringup.start()
        run(out, args.channel, bringup)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        status = 130
    except Exception as exc:
        print(f"demo failed: {exc}", file=sys.stderr)
        status = 1
    finally:
        bringup.stop()
        print("all nodes stopped", flush=True)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
