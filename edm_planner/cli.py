"""``edm-plan``: the command line of the planner (no ROS needed).

``edm-plan plan --geometry FILE.yaml --channel K --out DIR`` plans one channel
and writes the plan export (:mod:`edm_planner.records.plan_export`); the plan is
kept in the plan store shared with the nodes (:mod:`edm_planner.records.store`)
and an equal request is answered from there; ``edm-plan plan --all-channels``
plans every channel group of the blisk (as measured: each on its own walls) as
a task (:mod:`edm_planner.machining.blisk_plan`) and writes ``blisk.json``
beside the groups' exports. ``edm-plan export`` times a plan (an export
directory, a whole-blisk directory or a plan id in the store) on a machine and writes the NC
program and the timed CSV; ``edm-plan store list`` shows the stored plans.
Progress goes to stderr (a bar on a terminal, lines otherwise), a short summary
to stdout. Exit status: 0 on success, otherwise the
:class:`~edm_planner.errors.ErrorCode` value (1 .. 9; argparse's own usage
errors exit with 2), with ``error: NAME: message`` on stderr. A failed plan is
still written (error code, message, where the search stopped) for diagnosis;
``read_plan`` refuses it.
"""

import argparse
import json
import logging
import math
import os
import pathlib
import sys
import time
from dataclasses import replace

from .environment import configure_process

# this entry point's set-up, before numpy loads OpenBLAS and the core's kernel modules load (both read it then)
configure_process()

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from .environment import CACHE_ROOT  # noqa: E402  (after the set-up above)
from .errors import EdmError, ErrorCode  # noqa: E402
from .quick_exit import exit_now, interrupt_outside_imports  # noqa: E402
from .geometry.loader import load_geometry  # noqa: E402
from .planning.plan import PlanOptions  # noqa: E402
from .planning.planner import plan_channel  # noqa: E402
from .planning.search import METHODS, REFERENCES, SearchOptions  # noqa: E402
from .records.plan_check import verify_exported_plan  # noqa: E402
from .records.plan_export import _axes_csv, json_safe, read_plan, write_plan  # noqa: E402
from .records.store import (PlanStoreError, open_store, plan_cycle_of_stored, plan_to_stored,  # noqa: E402
                            request_key, roughing_to_stored, stored_to_plan)

# The electrode set, the NC export, roughing and the plots import their own modules inside their functions:
# heavy (the set designer, the post-processor, toppra, matplotlib) and needed by that command only, so the
# other commands, `edm-plan plan` first, do not pay for them (about 0.2 s here).

DEFAULT_CACHE = CACHE_ROOT
CACHE_HELP = "cache of distance fields, designed electrodes and workpiece deviations"


def _parser():
    d = SearchOptions()
    p = argparse.ArgumentParser(prog="edm-plan", description="Five-axis EDM electrode path planning for "
                                                             "shrouded blisks (units mm, rad, s).")
    sub = p.add_subparsers(dest="command", required=True)
    q = sub.add_parser("plan", help="plan one channel (or the whole blisk) and write the plan export directory",
                       description="Plan one channel: backward exit search, C2 spline, continuous certification; "
                                   "writes plan.json, electrode.stl, workpiece.stl and axes.csv to --out. Without "
                                   "an electrode design (the file's electrode section or an override below) the "
                                   "channel's electrode set is designed instead. With --all-channels the whole "
                                   "blisk: every group of channels whose walls agree (a blisk as measured; one "
                                   "group when nominal) planned on its representative channel's own walls as "
                                   "one task (local worker processes, or Ray tasks with --ray-address), each "
                                   "kept in the plan store as it finishes (a rerun plans only what is missing); "
                                   "--out gets one export per group (channel_K/) and blisk.json (groups, "
                                   "members, plan ids, clearances, status), from which `edm-plan export "
                                   "--all-channels DIR` writes the whole blisk's NC program. A fixed design plans "
                                   "each of its electrodes (or --electrode) with its machining cycle; a group "
                                   "that fails is named, the others are kept, and the exit status is its error.")
    q.add_argument("--geometry", required=True, metavar="FILE.yaml", help="blisk geometry file")
    q.add_argument("--channel", type=int, metavar="K", help="channel index 0 .. blade_count-1 (or --all-channels)")
    q.add_argument("--all-channels", action="store_true",
                   help="the whole blisk: every channel group as a task (see above)")
    q.add_argument("--workers", type=int, metavar="N",
                   help="--all-channels: worker processes (or a local Ray's CPUs) for the groups' tasks "
                        "(default: the CPU count, at most one per group)")
    q.add_argument("--out", required=True, metavar="DIR", help="export directory (created)")
    q.add_argument("--electrode", default="", metavar="ID",
                   help="electrode id (default: the first; with --all-channels every electrode of the design)")
    q.add_argument("--method", choices=METHODS, default=d.method)
    q.add_argument("--reference", choices=REFERENCES, default=d.reference, help="reference direction")
    q.add_argument("--axes", type=int, choices=(4, 5, 6), default=d.axes, help="machine axes")
    q.add_argument("--step", type=float, default=d.step, metavar="MM", help="node step along the reference")
    q.add_argument("--exit-side", choices=("auto", "upstream", "downstream"), default=d.exit_side)
    q.add_argument("--margin-blade", type=float, default=d.margin_blade, metavar="MM", help="Delta2")
    q.add_argument("--margin-hub-shroud", type=float, default=d.margin_hub_shroud, metavar="MM", help="Delta1")
    q.add_argument("--seed", type=int, default=d.seed, metavar="N")
    q.add_argument("--time-budget", type=float, default=d.time_budget, metavar="S")
    q.add_argument("--size-electrode", action="store_true",
                   help="find the smallest circumferential reduction with a certified path")
    e = q.add_argument_group("electrode design overrides (default: the geometry file's electrode section)")
    e.add_argument("--discharge-gap", type=float, metavar="MM")
    e.add_argument("--circumferential-reduction", type=float, metavar="RAD", help="h; the start value with "
                                                                                 "--size-electrode")
    e.add_argument("--radial-reduction", type=float, metavar="MM")
    e.add_argument("--split", choices=("none", "left_right", "front_rear"))
    e.add_argument("--split-overlap", type=float, metavar="MM")
    q.add_argument("--cache-dir", default=DEFAULT_CACHE, metavar="DIR", help=CACHE_HELP)
    q.add_argument("--machine", metavar="FILE.yaml",
                   help="machine file whose process section (regimes, wear) an electrode set is planned with "
                        "(default: config/machine.yaml)")
    q.add_argument("--single-regime", action="store_true",
                   help="an electrode set without roughing twins: the finishing electrodes erode everything")
    q.add_argument("--volume-resolution", type=float, default=0.5, metavar="MM",
                   help="voxel size of the removed-volume field of an electrode set (default 0.5)")
    q.add_argument("--stock-mesh", metavar="FILE.stl",
                   help="pre-machined stock (closed mesh, workpiece frame, mm) the electrodes start from, instead "
                        "of the solid channel")
    q.add_argument("--ray-address", default="", metavar="HOST:PORT",
                   help="design an electrode set on this Ray cluster ('auto': the one this machine belongs to; "
                        "started with `ray start --head`; 'local': a local Ray started for the design): its "
                        "pieces and proof shares run as Ray tasks (default: local worker processes); with "
                        "--all-channels each channel group is one Ray task there")
    _store_argument(q)
    q.add_argument("--replan", action="store_true", help="plan anew even if the store has the plan of this request")
    _progress_argument(q)
    q.add_argument("-v", "--verbose", action="store_true", help="log the planner's steps to stderr")
    g = sub.add_parser("geometry", help="validate a geometry file or show its figures")
    g.add_argument("action", choices=("validate", "info"))
    g.add_argument("file", metavar="FILE.yaml", nargs="?",
                   help="geometry YAML, or a STEP file (.step, .stp) of a whole blisk or one sector")
    g.add_argument("--geometry", dest="geometry_file", metavar="FILE", help="the same, as an option")
    c = sub.add_parser("check", help="re-check an exported plan with the exact clearance of every vertex",
                       description="Exact re-check of a plan export: every electrode vertex at every sample "
                                   "against the four channel surfaces; vertex steps; axes vs poses.")
    c.add_argument("plan_dir", metavar="DIR")
    c.add_argument("--geometry", required=True, metavar="FILE.yaml", help="the geometry the plan was made for")
    c.add_argument("--threshold", type=float, default=0.0, metavar="MM", help="smallest clearance accepted")
    c.add_argument("--cache-dir", default=DEFAULT_CACHE, metavar="DIR", help=CACHE_HELP)
    _progress_argument(c)
    c.add_argument("-v", "--verbose", action="store_true")
    t = sub.add_parser("plot", help="pictures of an exported plan: axis curves and the channel view")
    t.add_argument("plan_dir", metavar="DIR")
    t.add_argument("--out", metavar="DIR", help="where the pictures go (default: the plan directory)")
    t.add_argument("-v", "--verbose", action="store_true")
    g.add_argument("-v", "--verbose", action="store_true")
    x = sub.add_parser("export", help="time a plan on a machine and write the NC program and the timed CSV",
                       description="Time a certified plan (toppra, the machine's velocity, acceleration and jerk "
                                   "limits) and write <plan_id>.nc in the machine's NC dialect (its nc: section, "
                                   "or --dialect: G94 where no rotary axis moves, G93 where one does, F within the "
                                   "control's range) and <plan_id>.csv (time, then position, velocity, "
                                   "acceleration per axis). A plan with a machining cycle is written whole (clear, "
                                   "approach, feed, process, return, retract, clear; each leg timed rest to rest, "
                                   "'(PHASE ...)' lines, phase columns). An electrode set (its directory or id) is "
                                   "written as one program, a tool change at the clear position before each "
                                   "electrode; with --all-channels the whole blisk: each electrode through every "
                                   "channel (A indexed at the clear position), then the next, as a main program "
                                   "calling one subprogram per distinct channel pass (--nc-structure flat: DNC).")
    x.add_argument("source", metavar="PLAN",
                   help="a plan export directory, an electrode-set directory (set.json, from `edm-plan plan` "
                        "without a design), or a plan, set or program id in the plan store")
    x.add_argument("--all-channels", action="store_true",
                   help="the whole-blisk program of the source's electrode set: one NC program and one CSV")
    x.add_argument("--machine", metavar="FILE.yaml", help="machine file (default: config/machine.yaml)")
    x.add_argument("--out", metavar="DIR", help="where the files go (default: the export directory, or .)")
    x.add_argument("--format", choices=("nc", "csv", "both"), default="both")
    x.add_argument("--dialect", metavar="NAME|FILE.yaml",
                   help="NC dialect: a shipped one (iso_fanuc, beckhoff_edm_plus) or a dialect file (default: "
                        "the machine file's nc.dialect)")
    x.add_argument("--nc-structure", choices=("subprograms", "flat"),
                   help="subprograms (a main program calling each distinct channel pass) or flat (DNC: every "
                        "block in one program); default: the machine file's nc.structure")
    _store_argument(x)
    x.add_argument("-v", "--verbose", action="store_true")
    r = sub.add_parser("rough", help="plan the plunge roughing of one channel (Chen & Dong)",
                       description="Plunge roughing of one channel before EDM finishing (Chen & Dong): grooving "
                                   "positions midway between the blades, expansion lines in triangular order, tool "
                                   "poses whose flat bottom follows the shroud's inner surface with a uniform "
                                   "allowance (minimum one-sided Hausdorff distance). Keeps the plan in the store "
                                   "(`edm-plan export <plan id>` writes its NC program) and, with --out, writes "
                                   "roughing.json and axes.csv.")
    r.add_argument("--geometry", required=True, metavar="FILE.yaml", help="blisk geometry file")
    r.add_argument("--channel", required=True, type=int, metavar="K", help="channel index 0 .. blade_count-1")
    r.add_argument("--tool-radius", type=float, metavar="MM", help="flat-bottomed tool radius (default: r_max, "
                                                                   "eq. 11)")
    r.add_argument("--mu", type=float, metavar="MU", help="safeguard factor of eq. 11 (default 1.3)")
    r.add_argument("--allowance", type=float, metavar="MM", help="allowance on the shroud and blades (default 0.3)")
    r.add_argument("--out", metavar="DIR", help="also write roughing.json and axes.csv here")
    _store_argument(r)
    _progress_argument(r)
    r.add_argument("-v", "--verbose", action="store_true")
    s_ = sub.add_parser("store", help="the stored plans", description="List the plans of the plan store.")
    s_.add_argument("action", choices=("list",))
    _store_argument(s_)
    s_.add_argument("-v", "--verbose", action="store_true")
    return p


def _store_argument(parser):
    parser.add_argument("--store", default="", metavar="DIR",
                        help="plan store directory shared with the nodes (default: $EDM_PLANNER_PLAN_STORE or "
                             "~/.local/share/edm_planner/plan_store; 'none': do not use one)")


def _progress_argument(parser):
    parser.add_argument("--progress", choices=("auto", "bar", "lines", "none"), default="auto",
                        help="progress on stderr: a bar on a terminal, lines otherwise (auto)")


def _geometry(args, out):
    if (args.file is None) == (args.geometry_file is None):
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       "geometry: give the geometry file once, as FILE or --geometry FILE")
    args.file = args.file or args.geometry_file
    geometry = load_geometry(args.file)
    if args.action == "validate":
        print(f"{args.file}: valid, geometry id {geometry.geometry_id}, {geometry.blisk.blade_count} blades, "
              f"electrodes {[e.electrode_id for e in geometry.electrodes]}", file=out)
        return 0
    for key, value in geometry.info().items():
        if isinstance(value, float):
            value = f"{value:.6g}"
        elif isinstance(value, list) and value and isinstance(value[0], float):
            value = "[" + ", ".join(f"{v:.6g}" for v in value) + "]"
        print(f"{key}: {value}", file=out)
    return 0


def _check(args, out, err):
    geometry = load_geometry(args.geometry)
    plan = read_plan(args.plan_dir)
    if plan.geometry_id != geometry.geometry_id:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"the plan was made for geometry {plan.geometry_id[:12]}, "
                                                  f"{args.geometry} is {geometry.geometry_id[:12]}")
    progress = _Progress(err, args.progress)
    own = geometry.for_channel(plan.channel)          # a blisk as measured: the plan's channel's own walls
    check = verify_exported_plan(args.plan_dir, own.blisk, threshold=args.threshold,
                                 geometry_id=geometry.geometry_id, progress=progress, cache_dir=args.cache_dir,
                                 field_key=own.field_key)
    progress.close()
    clear = ", ".join(f"{s} {v:.4f}" for s, v in check.clearance_exact.items())
    print(f"clearance, exact minimum over every vertex at every sample [mm]: {clear}\nlargest vertex step {check.max_vertex_step:.4f} mm; "
          f"{check.exact_evaluations} exact evaluations in {check.elapsed:.1f} s", file=out)
    if not check.passed:
        raise EdmError(ErrorCode.INFEASIBLE, f"the plan does not pass: {check.message}")
    print("passed", file=out)
    return 0


def _plot(args, out):
    from .records import plots

    plan = read_plan(args.plan_dir)
    where = pathlib.Path(args.out or args.plan_dir)
    where.mkdir(parents=True, exist_ok=True)
    files = [plots.axis_curves(np.arange(len(plan.axes)), plan.axes, plan.axis_names, where / "axes_vs_index.png",
                               "sample index (feed order)", "Axis values along the certified path")]
    files += list(plots.channel_view(plan.workpiece_meshes(), plan.electrode_mesh, plan.poses,
                                     where / "channel.glb", where / "channel.png"))
    for f in files:
        print(f"wrote {f}", file=out)
    return 0


class _Progress:
    """Progress on stderr: a tqdm bar per stage, or lines (one per stage change, message or 10 % advance).

    ``mode`` "auto" draws bars on a terminal and lines otherwise (logs, CI); "none" is silent.
    """

    def __init__(self, stream, mode="lines"):
        if mode == "auto":
            mode = "bar" if getattr(stream, "isatty", lambda: False)() else "lines"
        self.stream, self.mode, self.t0, self.last = stream, mode, time.perf_counter(), (None, -1.0)
        self.bar = None

    def __call__(self, stage, fraction, nodes, reference_mm, message):
        if self.mode == "none":
            return
        if self.mode == "bar":
            return self._bar(stage, fraction, nodes, reference_mm, message)
        stage_then, fraction_then = self.last
        if stage == stage_then and fraction < min(fraction_then + 0.1, 1.0):
            return
        self.last = (stage, fraction)
        print(f"[{time.perf_counter() - self.t0:6.1f} s] {stage:<8} {100 * fraction:5.1f} %  "
              f"{self._detail(nodes, reference_mm, message)}".rstrip(), file=self.stream, flush=True)

    @staticmethod
    def _detail(nodes, reference_mm, message):
        """What a stage reports: search nodes and distance along the reference when it has them."""
        parts = [f"nodes {nodes:5d}"] if nodes else []
        parts += [f"reference {reference_mm:7.2f} mm"] if reference_mm else []
        return "  ".join(parts + [message])

    def _bar(self, stage, fraction, nodes, reference_mm, message):
        if self.bar is None or self.bar.desc != stage:
            self.close()
            self.bar = tqdm(total=100, desc=stage, file=self.stream, unit="%", dynamic_ncols=True,
                            bar_format="{desc:<8} {percentage:5.1f}%|{bar}| {elapsed}{postfix}")
        self.bar.n = round(100 * min(max(fraction, 0.0), 1.0), 1)
        self.bar.set_postfix_str(" ".join(self._detail(nodes, reference_mm, message).split()), refresh=False)
        self.bar.refresh()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _design(args, base):
    """The geometry's electrode design with the command line's overrides, or None without any."""
    keys = ("discharge_gap", "circumferential_reduction", "radial_reduction", "split", "split_overlap")
    changes = {k: getattr(args, k) for k in keys if getattr(args, k) is not None}
    return replace(base, **changes) if changes else None


def _plan(args, out, err):
    try:
        options = PlanOptions(search=SearchOptions(
            method=args.method, reference=args.reference, axes=args.axes, step=args.step,
            exit_side=args.exit_side, margin_blade=args.margin_blade, margin_hub_shroud=args.margin_hub_shroud,
            seed=args.seed, time_budget=args.time_budget), size_electrode=args.size_electrode)
    except ValueError as exc:
        raise EdmError(ErrorCode.INVALID_REQUEST, str(exc)) from None
    if (args.channel is None) == (not args.all_channels):
        raise EdmError(ErrorCode.INVALID_REQUEST, "plan: give --channel K or --all-channels (one of them)")
    if args.all_channels and args.size_electrode:
        raise EdmError(ErrorCode.INVALID_REQUEST, "--size-electrode plans one channel: not with --all-channels")
    if args.workers is not None and args.workers < 1:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"--workers must be at least 1, got {args.workers}")
    progress = _Progress(err, args.progress)
    progress("load", 0.0, 0, 0.0, args.geometry)
    geometry = load_geometry(args.geometry)
    if not args.all_channels and not 0 <= args.channel < geometry.blisk.blade_count:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"--channel must be in 0 .. {geometry.blisk.blade_count - 1}, got {args.channel}")
    try:
        os.makedirs(args.cache_dir, exist_ok=True)
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"--cache-dir {args.cache_dir}: {exc}") from None
    if args.all_channels:
        return _plan_blisk(args, geometry, options, progress, out, err)
    design = _design(args, geometry.design)
    store = open_store(args.store)
    if design is None and not args.electrode and not geometry.design_given and not args.size_electrode:
        return _plan_set(args, geometry, options, store, progress, out, err)
    key = request_key(geometry.geometry_id, args.channel, args.electrode, options, design)
    stored = None if (store is None or args.replan) else store.find(key)
    if stored is not None:
        plan = stored_to_plan(stored)
        progress("stored", 1.0, plan.metrics.node_count, 0.0, f"plan {plan.plan_id} from {store.path}")
    else:
        plan = plan_channel(geometry, args.channel, args.electrode, options, progress=progress,
                            cache_dir=args.cache_dir, design=design)
    path = write_plan(plan, args.out, geometry.blisk, cache_dir=args.cache_dir)
    not_kept = ""
    if stored is None and plan.success and store is not None:
        # after the export: a store that cannot take the plan (a full disk) costs no plan
        try:
            store.put(plan_to_stored(plan), key)
        except PlanStoreError as exc:
            not_kept = exc.message
            print(f"warning: the plan is written to {path.parent} but not kept in the plan store: {exc.message}",
                  file=err)
    progress("export", 1.0, plan.metrics.node_count, 0.0, str(path.parent))
    progress.close()
    if not plan.success:
        raise EdmError(plan.error_code, f"{plan.message} (furthest node {plan.furthest_node}, "
                                        f"{plan.furthest_reference:.3f} mm); diagnostics written to {path.parent}")
    m = plan.metrics
    lower = ", ".join(f"{s} {v:.4f}" for s, v in m.by_surface("clearance_lower_bound").items())
    exact = ", ".join(f"{s} {v:.4f}" for s, v in m.by_surface("clearance_exact").items())
    print(f"plan {plan.plan_id}: channel {plan.channel}, electrode {plan.electrode_id}, "
          f"method {options.search.method}, {len(plan.samples)} samples, {m.node_count} nodes, "
          f"path {m.path_length:.2f} mm, planned in {m.planning_time:.1f} s\n"
          f"clearance, certified lower bound over the path [mm]: {lower}\n"
          f"clearance, exact minimum over every vertex at every sample [mm]: {exact}\n"
          f"circumferential reduction {m.circumferential_reduction:.4f} rad\n"
          f"written to {path.parent}" + (f"\nfrom the plan store {store.path} (planned {stored.created}; "
                                         f"--replan plans anew)" if stored is not None else
                                         f"\nNOT kept in the plan store {store.path} (see the warning)" if not_kept
                                         else f"\nkept in the plan store {store.path}" if store is not None else ""),
          file=out)
    return 0


def _plan_set(args, geometry, options, store, progress, out, err):
    """No design named by the file or the command line: design the channel's electrode set."""
    # heavy, this command's only (see the note at the top)
    from .interference.fast import FastChannelField
    from .machining.electrode_set import SetDesigner, SetOptions
    from .process.set_process import add_process
    from .records.set_files import write_set

    progress("field", 0.0, 0, 0.0, "distance field")
    # a blisk as measured: the channel's own two blades, and the set machines only its group's channels
    channels = None if geometry.measured is None else next(
        members for _, members, _ in geometry.channel_groups() if args.channel in members)
    geometry = geometry.for_channel(args.channel)
    field = FastChannelField(geometry.blisk, spacing=0.1, cache_dir=args.cache_dir, cache_key=geometry.field_key)

    def on_step(record):
        """A SetProgress record -> a progress line: candidate, piece, sizing step, percent, time left (estimate)."""
        left = record.estimated_time_left
        parts = [record.where(), "time left ?" if left != left else f"time left ~{left:.0f} s", record.message]
        progress("set", record.fraction, 0, 0.0, " | ".join(p for p in parts if p))

    # heavy, this command's only (see the note at the top)
    from .cnc.config import default_machine_path, load_machine
    from .process.volume import load_stock_mesh

    process = load_machine(args.machine or default_machine_path()).process
    if args.single_regime:
        process = replace(process, rough_and_finish=False)
    stock = load_stock_mesh(args.stock_mesh) if args.stock_mesh else None
    designer = SetDesigner(geometry, field, options, SetOptions(time_budget=max(args.time_budget, 60.0) * 15),
                           field_cache=(args.cache_dir, geometry.field_key), detail=on_step, process=process,
                           process_resolution=args.volume_resolution, stock_mesh=stock, process_step=add_process,
                           ray_address=args.ray_address)
    result = designer.design(args.channel)
    not_kept = ""
    try:
        path = write_set(result, args.out, geometry.blisk, store, channels=channels, cache_dir=args.cache_dir)
    except PlanStoreError as exc:              # every file is written: only the store's copy is missing
        path, not_kept = pathlib.Path(args.out) / "set.json", exc.message
        print(f"warning: {exc.message}", file=err)
    progress.close()
    lines = [f"electrode set of channel {args.channel}: {result.message}",
             f"designed in {result.planning_time:.1f} s; candidates:"]
    for c in result.candidates:
        lines.append(f"  {c.name:<20} {c.status:<11} {c.reason[:160]}")
    if result.delivered is not None:
        if result.chosen is None:
            lines.append(f"NOT TO THE TOLERANCE: delivering {result.delivered.name}, the certified candidate that "
                         f"leaves the least stock; another operation must take what the stock map shows")
        for p in result.delivered.pieces:
            d, r = p.design, p.cycle.reach
            lines.append(f"  electrode {p.label}: plan {p.plan.plan_id}, h {d.circumferential_reduction:.4f} rad, "
                         f"radial reduction {d.radial_reduction:.3f} mm (radial reach {max(r.radial_reach, default=0):.3f} mm), "
                         f"cycle {len(p.cycle.samples)} samples in {len(p.cycle.legs)} legs")
        rep = result.delivered.removal
        lines.append(f"stock left (exact at wall samples {rep.spacing:.2f} mm apart, tolerance {rep.tolerance:g} mm):")
        for name, s in rep.surfaces.items():
            lines.append(f"  {name:<9} max {s.stock_max:8.4f} mm  mean {s.stock_mean:7.4f} mm  "
                         f"{100 * s.area_fraction_above_tolerance:6.2f} % of the area above "
                         f"({100 * s.area_fraction_beyond_inherent:5.2f} % beyond the corner rounding, up to "
                         f"{s.inherent_max:.3f} mm)  overcut {s.overcut_max:.4f} mm")
        d = result.delivered
        if d.allowance is not None:
            lines.append(f"roughing twins: allowance {d.allowance['allowance_mm']:g} +- {d.allowance['band_mm']:g} mm "
                         f"{'uniform' if d.allowance['uniform'] else 'NOT uniform'}; roughing overcut "
                         f"{d.rough_removal.overcut_max:.4f} mm")
        elif d.single_regime_reason:
            lines.append(f"single-regime set: {d.single_regime_reason}")
        if d.process is not None:
            lines.append(d.process.summary())
    lines.append(f"written to {path.parent} (set.json, stock.png, one export per electrode)"
                 + ("; NOT kept in the plan store (see the warning)" if not_kept else ""))
    print("\n".join(lines), file=out)
    if result.chosen is None:
        raise EdmError(ErrorCode.INFEASIBLE, result.message)
    return 0


#: the whole-blisk plan's summary in its --out directory (`edm-plan plan --all-channels`)
BLISK_FILE, BLISK_FORMAT = "blisk.json", "edm_planner.blisk_plan/1"


def _plan_blisk(args, geometry, options, progress, out, err):
    """--all-channels: every channel group planned as a task, kept as it finishes; blisk.json and a program."""
    # heavy, this command's only (see the note at the top)
    from .machining.blisk_plan import STORED, BliskRequest, GroupPlan, design_electrode_ids, plan_blisk
    from .machining.cycle import CycleOptions
    from .machining.electrode_set import SetDesigner, SetOptions, set_id_for
    from .records.certificate import NotCertifiedError
    from .records.set_files import write_set, write_stored_set

    gid, n = geometry.geometry_id, geometry.blisk.blade_count
    groups = geometry.channel_groups()
    design = _design(args, geometry.design)
    fixed = not (design is None and not args.electrode and not geometry.design_given)
    store = open_store(args.store)
    root = pathlib.Path(args.out)
    width = len(str(n - 1))
    request = BliskRequest(options, fixed_design=fixed, design=design, cache_dir=args.cache_dir)
    set_options = None
    if fixed:
        request = BliskRequest(options, True, design, design_electrode_ids(geometry, design, args.electrode),
                               CycleOptions(tolerance=SetOptions().tolerance), args.cache_dir)
    else:
        from .cnc.config import default_machine_path, load_machine
        from .process.set_process import add_process
        from .process.volume import load_stock_mesh

        process = load_machine(args.machine or default_machine_path()).process
        if args.single_regime:
            process = replace(process, rough_and_finish=False)
        stock = load_stock_mesh(args.stock_mesh) if args.stock_mesh else None
        set_options = SetOptions(time_budget=max(args.time_budget, 60.0) * 15)
        request = BliskRequest(options, False, None, (), CycleOptions(tolerance=set_options.tolerance), args.cache_dir,
                               set_options, process, add_process, args.volume_resolution, stock)

    def set_id_of(rep):
        return set_id_for(gid, rep, SetDesigner.machining_plan_options(options, geometry.design, set_options),
                          set_options, request.cycle_options, request.process, request.process_resolution,
                          request.stock_mesh[1] if request.stock_mesh else "")[0]

    def plan_key(rep, electrode_id):
        return request_key(gid, rep, electrode_id, options, design)      # edm-plan plan --channel's own key

    def stored(group):
        """The group's plans (with certified cycles) or set from the store; None where any is missing."""
        rep, members, devs = group
        if store is None or args.replan:
            return None
        try:
            if fixed:
                plans = []
                for eid in request.electrode_ids:
                    rec = store.find(plan_key(rep, eid))
                    plan = stored_to_plan(rec, str(store.path)) if rec is not None else None
                    if plan is None or plan.cycle is None or not plan.cycle.certified:
                        return None         # missing, or kept by `plan --channel` without its cycle
                    plans.append(plan)
                return GroupPlan(rep, members, devs, plans=plans, labels=list(request.electrode_ids),
                                 message=f"from the plan store {store.path}")
            seq = store.get_sequence(set_id_of(rep))
            if seq is None:
                return None
            records = [store.get(pid) for pid in seq.plan_ids]
            if None in records:
                return None
            plans = [stored_to_plan(rec, str(store.path)) for rec in records]
            return GroupPlan(rep, members, devs, plans=plans, labels=list(seq.meta.get("labels") or []),
                             message=f"set {seq.sequence_id} from the plan store {store.path}")
        except (PlanStoreError, NotCertifiedError) as exc:
            print(f"warning: group of channel {rep}: the plan store's copy is not used ({exc}); planning it anew",
                  file=err)
            return None

    exports = {}

    def keep(outcome):
        """Each group as it finishes: its export (a failed set's too, for its report), then the plan store."""
        rep = outcome.representative
        done[rep] = outcome
        where = root / f"channel_{rep:0{width}d}"
        blisk = geometry.for_channel(rep).blisk
        found = outcome.electrode_set
        try:
            if found is not None:
                path = write_set(found, where, blisk, None, channels=outcome.members, cache_dir=args.cache_dir)
                exports[rep] = [str((path.parent / e["export"]).relative_to(root))
                                for e in json.loads(path.read_text()).get("electrodes", [])]
            elif outcome.ok and not fixed:
                seq = store.get_sequence(set_id_of(rep))
                write_stored_set(outcome.plans, outcome.labels, seq.meta, where, blisk, cache_dir=args.cache_dir)
                exports[rep] = [str((where / label).relative_to(root)) for label in outcome.labels]
            elif outcome.ok:
                written = [write_plan(p, where / label, blisk, cache_dir=args.cache_dir)
                           for p, label in zip(outcome.plans, outcome.labels)]
                exports[rep] = [str(path.parent.relative_to(root)) for path in written]
        finally:
            _write_blisk_json(root, geometry, groups, args.geometry, exports, done)
        if store is None or outcome.status != "planned":
            return
        try:                        # after the files: a store that cannot take them costs no plan
            if fixed:
                for p, eid in zip(outcome.plans, request.electrode_ids):
                    store.put(plan_to_stored(p), plan_key(rep, eid))
            else:
                for p in outcome.plans:
                    store.put(plan_to_stored(p))
                meta = dict(found.to_dict(), labels=list(outcome.labels), channels=list(outcome.members))
                store.put_sequence(found.set_id, "electrode_set", [(p.plan_id, p.channel) for p in outcome.plans],
                                   json_safe(meta))
        except PlanStoreError as exc:
            print(f"warning: {outcome.name}: written to {where} but not kept in the plan store: {exc.message}",
                  file=err)

    done = {}
    t0 = time.perf_counter()

    def report(outcome, count, total, message=""):
        if outcome is None:
            line = message
        else:
            where = ("from the plan store" if outcome.status == STORED else
                     f"on node {outcome.node[:12] or '?'} ({outcome.worker or '?'}) in {outcome.elapsed_s:.1f} s")
            if outcome.ok:
                low, exact = outcome.clearance("clearance_lower_bound"), outcome.clearance("clearance_exact")
                line = (f"{outcome.name}: {outcome.status} {where}; plans {', '.join(p.plan_id for p in outcome.plans)}"
                        f"; clearance lower bound {min(low.values()):.4f} mm, exact minimum "
                        f"{min(exact.values()):.4f} mm")
            else:
                line = f"{outcome.name}: FAILED {where}: {outcome.error_code.name}: {_one_line(outcome.message)}"
            line = f"group {count}/{total} " + line
        if args.progress != "none":
            print(f"[{time.perf_counter() - t0:6.1f} s] {line}", file=err, flush=True)

    result = plan_blisk(geometry, request, workers=args.workers, ray_address=args.ray_address, stored=stored,
                        keep=keep, report=report, groups=groups)
    progress.close()
    if result.steps is not None and store is not None:
        try:
            store.put_sequence(result.program_id, "blisk_program", result.steps,
                               {"blade_count": n, "groups": [g.to_dict() for g in result.groups]})
        except PlanStoreError as exc:
            print(f"warning: the whole-blisk program is not kept in the plan store: {exc.message}", file=err)
    _write_blisk_json(root, geometry, groups, args.geometry, exports, done, result)
    lines = [f"whole blisk {gid[:12]}: {len(result.groups)} channel group(s) of {n} channels, "
             f"{'fixed design' if fixed else 'electrode set per group'}"
             + (f", planned on {result.executor}" if result.executor else "") + f", {result.elapsed_s:.1f} s"]
    lines.append("  group                                          status   plans               lower bound  exact min [mm]")
    for g in result.groups:
        low, exact = g.clearance("clearance_lower_bound"), g.clearance("clearance_exact")
        lines.append(f"  {g.name[:46]:<46} {g.status:<8} {','.join(p.plan_id[:8] for p in g.plans)[:19]:<19} "
                     + (f"{min(low.values()):11.4f}  {min(exact.values()):9.4f}" if g.ok else g.error_code.name))
    lines.append(f"written to {root} ({BLISK_FILE}, one export per group)")
    if result.failed:
        print("\n".join(lines), file=out)
        names = "; ".join(f"{g.name}: {g.error_code.name}: {_one_line(g.message)}" for g in result.failed)
        raise EdmError(result.failed[0].error_code,
                       f"{len(result.failed)} of {len(result.groups)} channel group(s) failed ({names}); the others "
                       f"are kept in {root}" + (f" and the plan store {store.path}" if store is not None else "")
                       + "; no whole-blisk program is written with a channel missing (a rerun plans only the "
                         "failed groups)")
    lines.append(f"whole-blisk program {result.program_id}: {len(result.steps)} steps (every channel once per "
                 f"electrode of its group); `edm-plan export --all-channels {root}` writes its NC program")
    print("\n".join(lines), file=out)
    return 0


def _write_blisk_json(root, geometry, channel_groups, source, exports, done, result=None):
    """blisk.json: the groups finished so far (``done``), and with ``result`` the whole (complete or not)."""
    groups = []
    for rep, members, devs in channel_groups:
        g = done.get(rep) if result is None else next(x for x in result.groups if x.representative == rep)
        entry = g.to_dict() if g is not None else {"representative": rep, "members": members,
                                                    "wall_deviation_mm": devs, "status": "pending"}
        entry["exports"] = exports.get(rep, []) if g is not None and g.ok else []
        groups.append(entry)
    doc = {"format": BLISK_FORMAT, "units": {"length": "mm", "angle": "rad", "time": "s"},
           "geometry_id": geometry.geometry_id, "geometry_file": str(source),
           "blade_count": geometry.blisk.blade_count, "complete": bool(result is not None and result.steps),
           "program_id": result.program_id if result is not None else "",
           "executor": result.executor if result is not None else "",
           "steps": None if result is None or result.steps is None else [[p, int(k)] for p, k in result.steps],
           "groups": groups}
    path = pathlib.Path(root) / BLISK_FILE
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(json_safe(doc), indent=1, allow_nan=False))
        os.replace(tmp, path)               # a reader never sees half a file
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"cannot write {path}: {exc}") from None
    return path


def _exported_plan(path):
    """(PlanCycle with the export's cycle, blade count) of a plan export directory."""
    # heavy, this command's only (see the note at the top)
    from .machining.program import PlanCycle, read_exported_cycle

    p = read_plan(path)
    cycle = read_exported_cycle(p.path, p.doc)
    plan = PlanCycle(p.doc["plan_id"], p.geometry_id, p.doc.get("electrode_id", ""), p.channel, p.axis_names,
                     p.final_pose, p.axes, cycle)
    return plan, p.doc.get("blade_count")


def _export_job(source, store_dir, all_channels):
    """What to export: dict(name, geometry_id, kind 'plan' | 'electrode_set' | 'blisk_program', plans, steps, pitch)."""
    # heavy, this command's only (see the note at the top)
    from .machining.program import blisk_program_steps, channel_program_steps

    def whole(kind, name, plans, steps, blade_count, program_name=None, channels=None):
        if not all_channels or kind == "blisk_program":
            pitch = 2 * math.pi / blade_count if blade_count else None
            return dict(name=name, kind=kind, plans=plans, steps=steps, pitch=pitch)
        if not blade_count:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"{name}: the blade count is unknown, so are the channels "
                                                      f"(export the set's directory or its program id instead)")
        ids = list(dict.fromkeys(p for p, _ in steps))
        if channels is not None and sorted(channels) != list(range(blade_count)):
            # a set of a blisk as measured machines its group's channels only: the others have walls of their own
            return dict(name=f"{name}.channels", kind="blisk_program", plans=plans,
                        steps=channel_program_steps([(steps[0][1], channels)], {steps[0][1]: ids}, blade_count,
                                                    partial=True),
                        pitch=2 * math.pi / blade_count)
        return dict(name=program_name or f"{name}.blisk", kind="blisk_program", plans=plans,
                    steps=blisk_program_steps(ids, blade_count), pitch=2 * math.pi / blade_count)

    path = pathlib.Path(source)
    if path.is_dir() and (path / BLISK_FILE).is_file():
        return _blisk_job(path)
    if path.is_dir() and (path / "set.json").is_file():
        try:
            doc = json.loads((path / "set.json").read_text())
            electrodes = doc["electrodes"]
            entries = [(e["plan_id"], path / e["export"]) for e in sorted(electrodes, key=lambda e: e["order"])]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise EdmError(ErrorCode.FILE_ERROR, f"{path / 'set.json'}: not an electrode set with its electrodes "
                                                 f"({exc!r}); was a set chosen?") from None
        plans, counts = {}, set()
        for plan_id, where in entries:
            plan, count = _exported_plan(where)
            if plan.plan_id != plan_id:
                raise EdmError(ErrorCode.FILE_ERROR, f"{where}: holds plan {plan.plan_id}, set.json names {plan_id}")
            plans[plan_id], counts = plan, counts | {count}
        if len(counts) != 1 or None in counts:
            raise EdmError(ErrorCode.FILE_ERROR, f"{path}: the electrodes' plan.json give blade counts {counts}")
        first = plans[entries[0][0]]
        name = doc.get("set_id") or f"set_{first.plan_id}"
        job = whole("electrode_set", name, plans, [(p, plans[p].channel) for p, _ in entries], counts.pop(),
                    doc.get("program_id"), doc.get("channels"))
        return dict(job, geometry_id=first.geometry_id)
    if path.is_dir():
        plan, count = _exported_plan(path)
        job = whole("plan", plan.plan_id, {plan.plan_id: plan}, [(plan.plan_id, plan.channel)], count)
        return dict(job, geometry_id=plan.geometry_id)
    store = open_store(store_dir)
    where = store.path if store else "(none)"
    stored = store.get(source) if store is not None else None
    if stored is not None:
        if all_channels:
            hint = f" (plan {source} belongs to set {stored.meta['set_id']}: export that)" \
                if stored.meta.get("set_id") else ""
            raise EdmError(ErrorCode.INVALID_REQUEST, f"--all-channels takes an electrode set: a set directory, or a "
                                                      f"set or program id of the store{hint}")
        plan = plan_cycle_of_stored(stored)
        return dict(name=plan.plan_id, kind="plan", plans={plan.plan_id: plan}, steps=[(plan.plan_id, plan.channel)],
                    pitch=None, geometry_id=plan.geometry_id)
    seq = store.get_sequence(source) if store is not None else None
    if seq is None:
        raise EdmError(ErrorCode.UNKNOWN_ID, f"{source!r} is neither a plan export directory nor a plan id in the "
                                             f"plan store {where} (nor an electrode-set directory, a set id or a "
                                             f"program id); `edm-plan store list` shows the stored plans")
    plans = {}
    for plan_id in seq.plan_ids:
        rec = store.get(plan_id)
        if rec is None:
            raise EdmError(ErrorCode.UNKNOWN_ID, f"{seq.kind} {seq.sequence_id}: its plan {plan_id} is not in the "
                                                 f"plan store {where}")
        plans[plan_id] = plan_cycle_of_stored(rec)
    blade_count = seq.meta.get("blade_count")
    program = seq.meta.get("program_id")
    if not blade_count and program:
        other = store.get_sequence(program)
        blade_count = other.meta.get("blade_count") if other is not None else None
    job = whole(seq.kind, seq.sequence_id, plans, seq.steps, blade_count, program)
    return dict(job, geometry_id=seq.geometry_id)


def _blisk_job(path):
    """The whole-blisk program of an `edm-plan plan --all-channels` directory: each group's plans from its exports."""
    # heavy, this command's only (see the note at the top)
    from .machining.program import channel_program_steps

    where = path / BLISK_FILE
    try:
        doc = json.loads(where.read_text())
        if doc.get("format") != BLISK_FORMAT:
            raise ValueError(f"format {doc.get('format')!r}, not {BLISK_FORMAT}")
        blade_count, groups = int(doc["blade_count"]), doc["groups"]
        failed = [g for g in groups if g["status"] not in ("planned", "stored")]
        entries = {int(g["representative"]): list(zip(g["plan_ids"], g["exports"])) for g in groups
                   if g not in failed}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"{where}: not a whole-blisk plan ({exc!r})") from None
    if failed or not doc.get("complete"):
        names = "; ".join(f"channels {g['members']} ({g['status']}: {g.get('message', '')[:120]})" for g in failed)
        why = names or "its run did not finish"
        raise EdmError(ErrorCode.INFEASIBLE, f"{where}: the whole-blisk plan is not complete ({why}): no program is "
                                             f"written with a channel missing; run `edm-plan plan --all-channels` "
                                             f"again (it plans only what is missing)")
    plans, geometry_ids = {}, set()
    for rep, pairs in entries.items():
        for plan_id, export in pairs:
            plan, count = _exported_plan(path / export)
            if plan.plan_id != plan_id or count != blade_count or plan.channel != rep:
                raise EdmError(ErrorCode.FILE_ERROR, f"{path / export}: holds plan {plan.plan_id} of channel "
                                                     f"{plan.channel} ({count} blades), {BLISK_FILE} names {plan_id} "
                                                     f"of channel {rep} ({blade_count} blades)")
            plans[plan_id], geometry_ids = plan, geometry_ids | {plan.geometry_id}
    if geometry_ids != {doc["geometry_id"]}:
        raise EdmError(ErrorCode.FILE_ERROR, f"{path}: plans of geometries {sorted(geometry_ids)}, {BLISK_FILE} "
                                             f"names {doc['geometry_id']}")
    steps = channel_program_steps([(int(g["representative"]), g["members"]) for g in groups],
                                  {rep: [p for p, _ in pairs] for rep, pairs in entries.items()}, blade_count)
    if [list(s) for s in steps] != doc["steps"]:
        raise EdmError(ErrorCode.FILE_ERROR, f"{where}: its steps are not those of its groups' plans")
    return dict(name=doc["program_id"], kind="blisk_program", plans=plans, steps=steps,
                pitch=2 * math.pi / blade_count, geometry_id=doc["geometry_id"])


def _export(args, out):
    # heavy, this command's only (see the note at the top)
    from .cnc.config import default_machine_path, load_machine
    from .cnc.nc import program_csv, trajectory_csv
    from .cnc.post import ProgramRun, write_program
    from .cnc.trajectory import plan_trajectory, time_run
    from .machining.program import program_runs

    job = _export_job(args.source, args.store, args.all_channels)
    machine_file = args.machine or str(default_machine_path())
    machine = load_machine(machine_file)
    name = job["name"]
    plan = job["plans"][job["steps"][0][0]]
    if job["kind"] == "plan" and plan.cycle is None:                  # a feed-only plan: its start pose to its end
        arrays = plan_trajectory(plan.samples, plan.axis_names, machine, final_pose=plan.final_pose)
        posts = [ProgramRun(arrays, plan.electrode_id or "electrode", plan.plan_id)]
        table, timed, what = trajectory_csv(arrays), [arrays], "feed"
    elif job["kind"] == "plan":
        runs = program_runs(job["steps"], job["plans"], job["pitch"])
        arrays = time_run(runs[0].legs, machine)
        posts = [ProgramRun(arrays, runs[0].label, plan.plan_id)]
        table, timed, what = trajectory_csv(arrays), [arrays], f"whole cycle, {len(plan.cycle.legs)} legs"
    else:
        runs = program_runs(job["steps"], job["plans"], job["pitch"])
        cache = {}
        timed = [time_run(r.legs, machine, cache=cache) for r in runs]
        posts = [ProgramRun(a, r.label, r.plan.plan_id) for a, r in zip(timed, runs)]
        table = program_csv(timed)
        channels = sorted({c for r in runs for c in r.channels})
        what = (f"{job['kind'].replace('_', ' ')}: {len(runs)} electrode(s) "
                f"({', '.join(r.label for r in runs)}) in {len(channels)} channel(s), {len(runs)} tool change(s)")
    nc, stats = write_program(posts, name, job["geometry_id"], job["kind"], machine, args.dialect, args.nc_structure)
    where = pathlib.Path(args.out or (args.source if pathlib.Path(args.source).is_dir() else "."))
    files = []
    try:
        where.mkdir(parents=True, exist_ok=True)
        if args.format in ("nc", "both"):
            files.append(where / f"{name}.nc")
            files[-1].write_text(nc)
        if args.format in ("csv", "both"):
            files.append(where / f"{name}.csv")
            files[-1].write_text(table)
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"cannot write to {where}: {exc}") from None
    points = sum(len(a.times) for a in timed)
    duration = sum(a.duration for a in timed)
    peaks = ", ".join(f"{a} {v:.4g}" for a, v in zip(timed[0].axis_names,
                                                   np.max([t.timed.peak_velocity for t in timed], axis=0)))
    print(f"{name} on machine {machine.name!r} ({machine_file}): {what}; {points} points, {duration:.3f} s"
          + (" without tool changes" if len(timed) > 1 else "") + f"; peak velocity [mm/s, rad/s]: {peaks}",
          file=out)
    print(f"NC program: {stats.blocks} motion blocks from {stats.points} timed points (points within "
          f"{stats.tolerance:g} mm of a block's line left out), {stats.subprograms} subprogram(s) called "
          f"{stats.calls} time(s), {len(nc.encode())} bytes, dialect {stats.dialect}"
          + (f"; {'; '.join(stats.notes)}" if stats.notes else ""), file=out)
    for f in files:
        print(f"wrote {f}", file=out)
    return 0


def _rough(args, out, err):
    # heavy, this command's only (see the note at the top)
    from .roughing import RoughingOptions, plan_roughing, roughing_plan_id

    changes = {k: v for k, v in (("tool_radius", args.tool_radius), ("mu", args.mu), ("allowance", args.allowance))
               if v is not None}
    try:
        options = RoughingOptions(**changes)
    except ValueError as exc:
        raise EdmError(ErrorCode.INVALID_REQUEST, getattr(exc, "message", str(exc))) from None
    progress = _Progress(err, args.progress)
    progress("load", 0.0, 0, 0.0, args.geometry)
    geometry = load_geometry(args.geometry)
    plan_id = roughing_plan_id(geometry.geometry_id, args.channel, options)
    store = open_store(args.store)
    stored = store.get(plan_id) if store is not None else None
    source = f"from the plan store {store.path} (planned {stored.created})" if stored is not None else ""
    if stored is None:
        result = plan_roughing(geometry.for_channel(args.channel).blisk, args.channel, options, progress=progress)
        stored = roughing_to_stored(result, plan_id, geometry.geometry_id)
        if store is not None:
            store.put(stored, plan_id)
            source = f"kept in the plan store {store.path}"
    progress.close()
    m = stored.meta
    if args.out:
        where = pathlib.Path(args.out)
        doc = {"format": "edm_planner.roughing/1", "units": {"length": "mm", "angle": "rad"},
               "plan_id": plan_id, "geometry_id": geometry.geometry_id, "channel": args.channel,
               "method": "plunge_roughing", **m, "axis_names": list(stored.axis_names),
               "reference_pose": stored.final_pose.reshape(-1),
               "positions": [{"label": lab, "tool_pose": p.reshape(-1), "initial_tool_pose": p0.reshape(-1),
                              "hausdorff_initial": h0, "hausdorff": h, "sample": int(i)}
                             for lab, p, p0, h0, h, i in zip(m["labels"], stored.arrays["tool_poses"],
                                                             stored.arrays["initial_tool_poses"],
                                                             stored.arrays["hausdorff_initial"],
                                                             stored.arrays["hausdorff"],
                                                             stored.arrays["bottom_index"])]}
        try:
            where.mkdir(parents=True, exist_ok=True)
            (where / "roughing.json").write_text(json.dumps(json_safe(doc), indent=1))
            (where / "axes.csv").write_text(_axes_csv(stored.axis_names, stored.samples))
        except OSError as exc:
            raise EdmError(ErrorCode.FILE_ERROR, f"cannot write to {where}: {exc}") from None
        source += f"; written to {where}"
    s0, s1 = m["stats_initial"], m["stats"]
    print(f"roughing plan {plan_id}: channel {args.channel}, {len(m['labels'])} plunge positions, "
          f"{m['line_count']} expansion lines, {len(stored.samples)} path samples\n"
          f"blade gap L_min {m['l_min']:.4f} mm, r_max {m['r_max']:.4f} mm, tool radius {m['tool_radius']:.4f} mm\n"
          f"error [mm]       mean |e|   std |e|    min       max       range\n"
          f"  initial        {s0['mean_abs']:.5f}  {s0['std_abs']:.5f}  {s0['min']:+.5f}  {s0['max']:+.5f}  "
          f"{s0['range']:.5f}\n"
          f"  optimised      {s1['mean_abs']:.5f}  {s1['std_abs']:.5f}  {s1['min']:+.5f}  {s1['max']:+.5f}  "
          f"{s1['range']:.5f}\n"
          f"mean absolute error {m['mae_reduction_percent']:.2f} % lower than at the initial poses "
          f"(the paper: 57.79 %); planned in {m['planning_time']:.1f} s\n{source}".rstrip(), file=out)
    return 0


def _store(args, out):
    store = open_store(args.store)
    if store is None:
        raise EdmError(ErrorCode.INVALID_REQUEST, "--store none: there is no store to list")
    rows = store.list()
    print(f"{len(rows)} plan(s) in {store.path}", file=out)
    for r in rows:
        print(f"{r['plan_id']}  {r['kind']:<8} geometry {r['geometry_id'][:12]}  channel {r['channel']:3d}  "
              f"electrode {r['electrode_id'] or '-':<8} {r['method']:<18} {r['created']}", file=out)
    seqs = store.list_sequences()
    print(f"{len(seqs)} sequence(s) (electrode sets, whole-blisk programs; `edm-plan export ID`)", file=out)
    for r in seqs:
        print(f"{r['sequence_id']}  {r['kind']:<14} geometry {r['geometry_id'][:12]}  {r['created']}", file=out)
    return 0


def main(argv=None, out=None, err=None):
    """Entry point of ``edm-plan``; returns the exit status."""
    out = out or sys.stdout
    err = err or sys.stderr
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=err,
                        format="%(name)s: %(message)s")
    try:
        if args.command == "geometry":
            return _geometry(args, out)
        if args.command == "check":
            return _check(args, out, err)
        if args.command == "plot":
            return _plot(args, out)
        if args.command == "export":
            return _export(args, out)
        if args.command == "store":
            return _store(args, out)
        if args.command == "rough":
            return _rough(args, out, err)
        return _plan(args, out, err)
    except EdmError as exc:
        print(f"error: {exc.code.name}: {_one_line(exc.message)}", file=err)
        return int(exc.code)
    except KeyboardInterrupt:
        print("error: interrupted", file=err)
        return 130
    except Exception as exc:     # a bug: one line for the user, the traceback with -v
        logging.getLogger(__name__).info("internal error", exc_info=True)      # shown with -v
        print(f"error: {ErrorCode.INTERNAL.name}: {_one_line(repr(exc))} (a bug: please report it; -v shows "
              f"the traceback)", file=err)
        return int(ErrorCode.INTERNAL)


def _one_line(message):
    """The message on one line (YAML errors and file names may hold line breaks)."""
    return " ".join(part.strip() for part in str(message).splitlines() if part.strip())


def run():
    """The ``edm-plan`` console script: :func:`main` (Ctrl-C never inside an import:
    :func:`.quick_exit.interrupt_outside_imports`), then the process ends without Python's final teardown
    (:func:`.quick_exit.exit_now`: about 0.6 s of a command's time, Zen 3)."""
    interrupt_outside_imports()
    exit_now(main())


if __name__ == "__main__":
    run()
