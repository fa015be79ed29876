"""``make demo``'s cell controller: the steps it drives over DDS while and after the nodes come up.

:mod:`.demo` starts the nodes (:mod:`.bringup`) first and then imports this module, which imports rclpy, the
messages and the core while the nodes import theirs. What the steps do: :mod:`.demo`.
"""

import csv
import importlib
import json
import math
import pathlib
import shutil
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus
from edm_planner_msgs.action import ExecutePlan, PlanElectrodeSet
from edm_planner_msgs.msg import AxisPoint, BliskGeometry, ElectrodeDesign
from edm_planner_msgs.srv import CheckInterference, LoadGeometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from trajectory_msgs.msg import JointTrajectory

from ...environment import configure_process

# set-up before the core's kernel modules load (numba reads its cache directory then); done by demo already
configure_process()

from ...geometry.frames import rotation_about_x
from ...interference import SURFACES as SURFACE_NAMES
from ...ros.shared import LATCHED
from ...records.plan_export import read_plan
from ...ros.action_client import LockedActionClient
from ...ros.conversions import msg_to_mesh

TRAJECTORY_TOPIC = "/edm_controller/joint_trajectory"


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


class _Pending:
    """A service call sent at once and answered later (:meth:`result`); every wait has a deadline and checks the
    nodes alive."""

    def __init__(self, node, srv_type, name, request, timeout, bringup):
        self.node, self.name, self.timeout, self.bringup = node, name, timeout, bringup
        self.client = node.create_client(srv_type, name)
        self.deadline = time.monotonic() + timeout
        while not self.client.wait_for_service(timeout_sec=0.5):
            bringup.check_alive()
            if time.monotonic() > self.deadline:
                raise RuntimeError(f"service {name} not available after {timeout:.0f} s")
        self.future = self.client.call_async(request)

    def result(self):
        while not self.future.done():
            self.bringup.check_alive()
            if time.monotonic() > self.deadline:
                raise RuntimeError(f"service {self.name} did not answer within {self.timeout:.0f} s")
            time.sleep(0.02)
        self.node.destroy_client(self.client)
        return self.future.result()


def _call(node, srv_type, name, request, timeout, bringup):
    return _Pending(node, srv_type, name, request, timeout, bringup).result()


def _action(node, action_type, name, goal, timeout, bringup, on_feedback=None):
    """Send an action goal and wait for its result (every wait with a deadline, the nodes checked alive).

    Returns (status, result). Interrupted (Ctrl-C), the goal is cancelled before the exception goes on.
    """

    client = LockedActionClient(node, action_type, name)
    deadline = time.monotonic() + timeout

    def wait(future, what):
        while not future.done():
            bringup.check_alive()
            if time.monotonic() > deadline:
                raise RuntimeError(f"action {name}: {what} not within {timeout:.0f} s")
            time.sleep(0.02)
        return future.result()

    try:
        while not client.wait_for_server(timeout_sec=0.5):
            bringup.check_alive()
            if time.monotonic() > deadline:
                raise RuntimeError(f"action server {name} not available after {timeout:.0f} s")
        handle = wait(client.send_goal_async(goal, feedback_callback=(
            None if on_feedback is None else lambda m: on_feedback(m.feedback))), "goal response")
        if not handle.accepted:
            raise RuntimeError(f"action {name}: goal rejected (see the node's log)")
        try:
            response = wait(handle.get_result_async(), "result")
        except KeyboardInterrupt:
            cancel = handle.cancel_goal_async()
            end = time.monotonic() + 5.0
            while not cancel.done() and time.monotonic() < end:
                time.sleep(0.02)
            raise
        return response.status, response.result
    finally:
        client.destroy()


class SetFeedbackLines:
    """PlanElectrodeSet feedback as lines: one per candidate or piece change, or 10 % advance."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stdout
        self.where, self.fraction, self.count = None, -1.0, 0

    def __call__(self, fb):
        where = (fb.candidate, fb.piece)
        if where == self.where and fb.fraction < self.fraction + 0.1:
            return
        self.where, self.fraction = where, fb.fraction
        self.count += 1
        left = "time left ?" if math.isnan(fb.estimated_time_left) else f"time left ~{fb.estimated_time_left:.0f} s"
        parts = [f"candidate {fb.candidate_index + 1}/{fb.candidate_count} {fb.candidate}" if fb.candidate else "",
                 f"piece {fb.piece_index + 1}/{fb.piece_count} {fb.piece}" if fb.piece else "",
                 f"step {fb.sizing_step} {fb.sizing_parameter}" if fb.sizing_parameter else ""]
        print(f"    {100 * fb.fraction:5.1f} %  {fb.elapsed:6.1f} s  {left:<17} "
              f"{', '.join(p for p in parts if p) or fb.message[:80]}", file=self.stream, flush=True)


class FollowLines:
    """ExecutePlan feedback as lines: one per phase change or 10 % of the trajectory."""

    def __init__(self):
        self.phase, self.fraction = None, -1.0

    def __call__(self, fb):
        if fb.phase == self.phase and fb.fraction < self.fraction + 0.1:
            return
        self.phase, self.fraction = fb.phase, fb.fraction
        print(f"    {fb.executed_time:7.1f} of {fb.duration:.1f} s  {fb.phase} (channel {fb.channel})", flush=True)


def _require(response, what):
    ok = response.success if hasattr(response, "success") else response.error_code.val == 0
    if not ok:
        raise RuntimeError(f"{what} failed (error code {response.error_code.val}): {response.message}")
    return response


def _design_msg(d):
    """An ElectrodeDesign message of a design dict (set.json): the CheckInterference override of one electrode."""

    nan = float("nan")
    rng = d.get("axial_range") or [nan, nan]
    return ElectrodeDesign(discharge_gap=float(d["discharge_gap"]),
                           circumferential_reduction=float(d["circumferential_reduction"]),
                           reduction_side=d["reduction_side"], radial_reduction=float(d["radial_reduction"]),
                           axial_start=float(rng[0]), axial_end=float(rng[1]), split=d["split"],
                           split_fraction=float(d["split_fraction"]), split_overlap=float(d["split_overlap"]))


def _cycle_csv(path):
    """(axis names, (n, k) axis values, phases) of an export's cycle.csv."""

    with open(path) as f:
        rows = list(csv.reader(f))
    axes = [h for h in rows[0][2:] if h.endswith(("_mm", "_rad"))]      # then the leg's regime
    names = [h.split("_")[0] for h in axes]
    return names, np.array([[float(v) for v in r[2:2 + len(axes)]] for r in rows[1:]]), [r[0] for r in rows[1:]]


class Pictures:
    """The demo's pictures, drawn one after another in a thread of their own while the steps wait on the nodes.

    matplotlib (imported here first: about 0.5 s, 2 s under load) and the drawing (about 3 s, Zen 3) would
    otherwise run after the last step. One thread: pyplot's state is never touched by two at once.
    :meth:`wait` returns what each drawing returned, or raises its error.
    """

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="demo-pictures")
        self._plots = self._pool.submit(importlib.import_module, "edm_planner.records.plots")
        self._jobs = []

    def draw(self, fn, *args, **kwargs):
        """Queue ``fn(plots, *args, **kwargs)`` (``plots``: :mod:`edm_planner.records.plots`)."""
        self._jobs.append(self._pool.submit(lambda: fn(self._plots.result(), *args, **kwargs)))

    def wait(self, timeout):
        deadline = time.monotonic() + timeout
        return [job.result(timeout=max(0.0, deadline - time.monotonic())) for job in self._jobs]

    def close(self):
        self._pool.shutdown(wait=False, cancel_futures=True)


def run(out_dir, channel, bringup, timeout=600.0, set_timeout=3600.0, follow=False):
    pictures = Pictures()
    share = pathlib.Path(sys.prefix) / "share" / "edm_planner" / "config"

    # Ctrl-C must reach the demo as KeyboardInterrupt (stop the nodes, exit 130), not shut rclpy down
    # under a service call in flight (rclpy's own handler), which would read as a failed step
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("edm_demo_cell_controller")
    received = []
    node.create_subscription(JointTrajectory, TRAJECTORY_TOPIC, received.append, 10)
    geometries = {}           # the loader's latched geometry: the channel surfaces for the 3D view
    node.create_subscription(BliskGeometry, "geometry",
                             lambda m: geometries.__setitem__(m.summary.geometry_id, m), LATCHED)
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
                  f"min channel width {s.min_channel_width:.3f} mm; no electrode design in the file")
        with Step(f"PlanElectrodeSet: channel {channel}, the planner designs the electrode set"):
            # the action: its feedback (candidate, piece, sizing step, percent, time left) printed as lines
            _, res = _action(node, PlanElectrodeSet, "plan_electrode_set",
                             PlanElectrodeSet.Goal(geometry_id=geo.geometry_id, channel=channel, write_export=True),
                             set_timeout, bringup, SetFeedbackLines())
            if not res.plan_ids:
                _require(res, "PlanElectrodeSet")
            for c in res.candidates:
                print(f"    candidate {c.name:<19} {c.status:<11} {c.reason[:110]}")
            if not res.success:
                print(f"    NOT TO THE TOLERANCE: {res.message[:300]}")
            print(f"    set {res.set_id}: {len(res.plan_ids)} electrode(s) {list(res.electrode_labels)}, "
                  f"designed in {res.planning_time:.1f} s")
            for e in res.process:
                print(f"    process {e.label:<12} {e.regime:<6} {e.condition_code:<5} {e.removed_volume:7.0f} mm^3 "
                      f"[{e.removed_volume_lower:.0f}, {e.removed_volume_upper:.0f}]  eroding {e.eroding_time / 3600:5.2f} h"
                      f"  wear {e.worst_face_wear:.3f} mm/channel on its worst face (limit {e.wear_limit:g} mm): "
                      f"{e.electrodes_per_channel} per channel, {e.electrodes_per_blisk} per blisk")
            if res.process:
                print(f"    process (model estimates, config/machine.yaml): {res.channel_removed_volume:.0f} mm^3 and "
                      f"{res.channel_eroding_time / 3600:.2f} h eroding per channel, "
                      f"{res.blisk_eroding_time / 3600:.1f} h for the blisk; Liu et al. 2024 took 4.07-4.25 h per "
                      f"channel on another blisk and machine")
        set_doc = json.loads((pathlib.Path(res.export_path) / "set.json").read_text())
        delivered = next(c for c in set_doc["candidates"] if c["name"] == set_doc["delivered"])
        designs = {p["label"]: p for p in delivered["pieces"]}
        label0 = res.electrode_labels[0]
        # the clearance checks asked for now: the interference_checker works on them while the axis_bridge times
        # the cycles below (their steps then print what each answered)
        checks = {}
        for label in res.electrode_labels:
            names, q, _ = _cycle_csv(pathlib.Path(res.export_path) / label / "cycle.csv")
            req = CheckInterference.Request(geometry_id=geo.geometry_id, channel=channel,
                                            electrode_id=designs[label]["electrode_id"],
                                            electrode=_design_msg(designs[label]["design"]),
                                            method=CheckInterference.Request.METHOD_FAST, axis_names=names)
            req.axis_values = [AxisPoint(positions=row) for row in q.tolist()]
            checks[label] = len(q), _Pending(node, CheckInterference, "check_interference", req, timeout, bringup)
        pictures.draw(_channel_picture, geometries, geo.geometry_id, channel,
                      pathlib.Path(res.export_path) / label0, out_dir)
        trajectories = []
        for i, label in enumerate(res.electrode_labels):
            with Step(f"ExecutePlan: set {res.set_id}, electrode {i} ({label}): its whole cycle"):
                before = len(received)
                # the action; with --follow its feedback along the trajectory, in real time
                status, ex = _action(node, ExecutePlan, "execute_plan",
                                     ExecutePlan.Goal(plan_id=res.set_id, channel=channel, dry_run=False,
                                                      electrode=i, follow=follow),
                                     timeout + (3 * 3600.0 if follow else 0.0), bringup,
                                     FollowLines() if follow else None)
                _require(ex, "ExecutePlan")
                if status != GoalStatus.STATUS_SUCCEEDED:
                    raise RuntimeError(f"ExecutePlan ended with goal status {status}: {ex.message}")
                deadline = time.monotonic() + 30.0
                while len(received) == before:
                    if time.monotonic() > deadline:
                        raise RuntimeError(f"no JointTrajectory received on {TRAJECTORY_TOPIC}")
                    time.sleep(0.05)
                trajectories.append((label, ex, received[-1]))
                if i == 0:
                    pictures.draw(_axis_pictures, label, ex, received[-1],
                                  pathlib.Path(res.export_path) / label / "cycle.csv", out_dir)
                phases = ", ".join(f"{n} {t:.1f} s" for n, t in zip(ex.phase_names, ex.phase_start_times))
                print(f"    {ex.point_count} points, {ex.duration:.1f} s ({ex.duration / 3600:.2f} h; generator on "
                      f"{ex.eroding_time / 3600:.2f} h in {sorted(set(r for r in ex.regime_names if r))}); "
                      f"phases from: {phases}")
                if ex.next_electrode:
                    print(f"    then change the tool: {ex.next_electrode}")
        clearances = {}
        for label in res.electrode_labels:
            with Step(f"CheckInterference: the {label} electrode along its whole cycle (fast method)"):
                samples, pending = checks[label]
                chk = _require(pending.result(), "CheckInterference")
                clearances[label] = np.array([[c.suction, c.pressure, c.hub, c.shroud] for c in chk.clearances])
                print(f"    {samples} samples; smallest {clearances[label].min():.4f} mm (fast value, error bound "
                      f"{chk.error_bound * 1e3:.1f} um)")
        margin = float(set_doc["candidates"][0]["pieces"][0]["design"]["discharge_gap"]) - 0.02
        allc = np.vstack(list(clearances.values()))
        pictures.draw(lambda plots: plots.clearance_plot(
            np.arange(len(allc)), allc, [margin] * 4, out_dir / "clearance.png",
            f"fast values of CheckInterference, exact within +-{chk.error_bound * 1e3:.1f} um",
            xlabel="cycle sample (" + ", then ".join(clearances) + ")"))
        with Step(f"plots and 3D view in {out_dir}"):
            stock_png = pathlib.Path(res.export_path) / "stock.png"
            for name in ("stock.png", "stock.glb", "process.png"):   # the removal proof, the process
                if (stock_png.parent / name).exists():
                    shutil.copyfile(stock_png.parent / name, out_dir / name)
            pictures.wait(timeout)
        m = res.metrics
        print("\nSummary")
        print(f"  geometry     default blisk, id {geo.geometry_id[:12]}, channel {channel}, no design given")
        print(f"  set          {set_doc['delivered']}: {', '.join(res.electrode_labels)} "
              f"({'machines the channel to the tolerance' if res.success else 'NOT to the tolerance'}), "
              f"designed in {res.planning_time:.1f} s, set {res.set_id}, whole-blisk program {res.program_id}")
        print(f"  feed clearance [mm]{'':<27}" + "".join(f"{n:>10}" for n in SURFACE_NAMES))
        for label, metrics in zip(res.electrode_labels, m):
            for i, (kind, name) in enumerate((("certified lower bound, whole path", "clearance_lower_bound"),
                                              ("exact minimum, vertices at samples", "clearance_exact"))):
                print(f"  {label if i == 0 else '':<12} {kind:<34}"
                      + "".join(f"{getattr(metrics, f'{name}_{n}'):>10.4f}" for n in SURFACE_NAMES))
        removal = delivered.get("removal", {})
        print(f"  stock left   exact at wall samples {removal.get('accuracy', {}).get('sample_spacing_mm')} mm "
              f"apart, tolerance {removal.get('tolerance_mm')} mm:")
        for name, f in sorted(removal.get("surfaces", {}).items(),
                              key=lambda kv: SURFACE_NAMES.index(kv[0])):
            print(f"    {name:<9} max {f['stock_max_mm']:.4f} mm, mean {f['stock_mean_mm']:.4f} mm, "
                  f"{100 * f['area_fraction_above_tolerance']:.2f} % of the area above "
                  f"({100 * (f['area_fraction_beyond_inherent'] or 0):.2f} % beyond the corner rounding), "
                  f"overcut {f['overcut_max_mm']:.4f} mm")
        allowance = delivered.get("roughing_allowance")
        if allowance:
            shares = ", ".join(f"{k} {100 * v['share_within_band']:.1f} %" for k, v in allowance["surfaces"].items())
            print(f"  roughing     allowance {allowance['allowance_mm']:g} +- {allowance['band_mm']:g} mm "
                  f"{'uniform' if allowance['uniform'] else 'NOT uniform'} ({shares} of the judged area)")
        for note in delivered.get("roughing_notes", []):
            print(f"               {note[:160]}")
        for label, ex, _ in trajectories:
            print(f"  {label:<12} cycle {ex.duration:.1f} s = {ex.duration / 3600:.2f} h (generator on "
                  f"{ex.eroding_time / 3600:.2f} h, {ex.removed_volume:.0f} mm^3), {ex.point_count} points")
        if res.process:
            print(f"  process      {res.channel_eroding_time / 3600:.2f} h eroding per channel, "
                  f"{res.blisk_eroding_time / 3600:.1f} h for the blisk (model estimates, config/machine.yaml; "
                  f"Liu et al. 2024: 4.07-4.25 h per channel on another blisk); process.png")
        print(f"  written      {res.export_path} (set.json, stock.png, process.png, one export per electrode), "
              f"{out_dir}/*.png (process.png: time and wear), {out_dir}/channel.glb")
    finally:
        pictures.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def _axis_pictures(plots, label, ex, traj, cycle_csv, out_dir):
    """The first electrode's axis curves: as sent to the controller (against time), and along its certified cycle
    (against the sample index, cf. Huang Fig. 7)."""
    t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in traj.points])
    qt = np.array([p.positions for p in traj.points])
    plots.axis_curves(t, qt, list(traj.joint_names), out_dir / "axes_vs_time.png", "time [s]",
                      f"The {label} electrode's cycle as sent to the controller ({ex.duration:.1f} s)",
                      marks=list(zip(ex.phase_names, ex.phase_start_times)))
    names, q, phase = _cycle_csv(cycle_csv)
    plots.axis_curves(np.arange(len(q)), q, names, out_dir / "axes_vs_index.png", "sample index",
                      f"Axis values along the {label} electrode's certified cycle (cf. Huang Fig. 7)",
                      marks=[(p, i) for i, p in enumerate(phase) if i == 0 or phase[i - 1] != p])


def _channel_picture(plots, geometries, geometry_id, channel, export_dir, out_dir):
    """The first electrode's swept positions in the channel (GLB and PNG), on the loader's latched geometry."""
    deadline = time.monotonic() + 30.0
    while geometry_id not in geometries:              # latched: here already, or on its way
        if time.monotonic() > deadline:
            raise RuntimeError("the geometry was not received on the latched 'geometry' topic")
        time.sleep(0.05)
    published = geometries[geometry_id]
    turn = rotation_about_x(channel * published.summary.blade_pitch)      # published: channel 0
    surfaces = {label: msg_to_mesh(m).apply_transform(turn)
                for label, m in zip(published.surface_labels, published.surfaces)}
    export = read_plan(export_dir)
    plots.channel_view(surfaces, export.electrode_mesh, export.poses, out_dir / "channel.glb", out_dir / "channel.png")
