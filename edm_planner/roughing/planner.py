"""Plunge-roughing planner for a shrouded channel (Chen & Dong): the one entry point.

:func:`plan_roughing` chains the parts: blade gap and tool radius (eq. 10-11),
initial positions and travel order (eq. 12-13, ``positions``), the pose
optimisation of every position (eq. 1-9 and section 3.2, ``hausdorff``), the
error statistics (eq. 14-15, ``stats``) and the machine axis path
(``path``). Units: mm and rad; poses are 4x4 transforms tool frame -> W (see
``path`` for the frames).

The initial pose of a position is a radial plunge: bottom centre on the
target surface (the shroud's inner surface offset by the allowance), tool
axis along the radius towards the blisk axis. The paper does not say how its
initial poses were oriented; the radial plunge is the pose a four-axis
(indexing) machine would use.

The setting is the paper's shroud-enabled milling: the blades stand on the
shroud, the hub is not there yet, the tool enters the channel from the hub
side (radially inwards of it). The hub is therefore no obstacle; the retract
height takes the tool bottom below the hub radius, clear of the blades.
"""

import hashlib
import json
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from ..errors import EdmError, ErrorCode
from .distance import RevolutionDistance
from .hausdorff import ToolPoseModel, bottom_points, optimise_pose
from .options import RoughingOptions
from .path import AxisPath, axes_for, plunge_path, reference_pose, tool_poses
from .positions import blade_root_data, max_tool_radius, minimum_gap, plan_positions
from .stats import ErrorStats, error_stats, reduction_percent

#: the paper's reported reduction of the mean absolute error (section 3.3) [%]
PAPER_MAE_REDUCTION_PERCENT = 57.79


@dataclass
class RoughingResult:
    """A plunge-roughing plan of one channel.

    Positions are stored grooving first (see ``positions.triangular_order``);
    ``order`` gives the machining order. Units: mm, rad.

    Attributes
    ----------
    channel : int
    options : RoughingOptions
    l_min : float
        Eq. 10 [mm].
    r_max : float
        Eq. 11 [mm].
    tool_radius : float
        The radius used [mm] (r_max unless given).
    labels : list of str
        ``O<i>`` grooving, ``A<i>``/``B<i>``/``C<i>``/``L<i>.<j>`` on expansion line i.
    order : (n,) int
        Travel order, indices into the positions.
    poses : (n, 4, 4) float
        Optimised tool poses in W: origin at the centre of the flat bottom, z = the tool axis from
        the bottom up the shank, x and y as the machine's axes turn them (``path``).
    initial_poses : (n, 4, 4) float
        The radial-plunge initial poses, same frame.
    hausdorff_initial, hausdorff_paper, hausdorff : (n,) float
        One-sided Hausdorff distance of the discretised bottom to the target surface at the
        initial pose, after the paper's iteration (with its secondary optimisation), and final [mm].
    errors_initial, errors : (n, m) float
        Signed errors of the m bottom points (positive: short of the target) [mm].
    stats_initial, stats_paper, stats : ErrorStats
        Eq. 14-15 over all bottom points: initial, paper's iteration only, final.
    iterations, polish_iterations : (n,) int
        LPs of the paper's iteration and of the polish per position.
    secondary : (n,) bool
        Where the secondary optimisation ran.
    line_count : int
        N_V1 (eq. 13); ``line_count_value`` the unrounded value.
    groove_count : int
    line_spacing : float
        [mm]
    groove_steps : (groove_count - 1,) float
        Eq. 12 steps [mm].
    machining_length : float
        S of eq. 13 [mm].
    axis_names : tuple of str
        ("X", "Y", "Z", "A", "C").
    samples : (N, 5) float
        Untimed axis path [mm, rad]; the bridge's ``plan_trajectory(samples, axis_names, machine,
        final_pose=reference_pose)`` times it.
    reference_pose : (4, 4) float
        The carrier frame at zero axis values: ``axis_poses(reference_pose, axis_names, samples)``
        are the carrier frames along the path, ``... @ path.TOOL_IN_CARRIER`` the tool frames.
    bottom_index : (n,) int
        Sample index of the optimised pose of the i-th position in travel order.
    retract_distances : (n,) float
        Retract distance along the tool axis, travel order [mm].
    planning_time : float
        [s]
    """

    channel: int
    options: RoughingOptions
    l_min: float
    r_max: float
    tool_radius: float
    labels: list
    order: np.ndarray
    poses: np.ndarray
    initial_poses: np.ndarray
    hausdorff_initial: np.ndarray
    hausdorff_paper: np.ndarray
    hausdorff: np.ndarray
    errors_initial: np.ndarray
    errors: np.ndarray
    stats_initial: ErrorStats
    stats_paper: ErrorStats
    stats: ErrorStats
    iterations: np.ndarray
    polish_iterations: np.ndarray
    secondary: np.ndarray
    line_count: int
    line_count_value: float
    groove_count: int
    line_spacing: float
    groove_steps: np.ndarray
    machining_length: float
    axis_names: tuple
    samples: np.ndarray
    reference_pose: np.ndarray
    bottom_index: np.ndarray
    retract_distances: np.ndarray
    planning_time: float
    path: AxisPath = field(repr=False, default=None)

    @property
    def position_count(self):
        return len(self.poses)

    @property
    def mae_reduction_percent(self):
        """Reduction of the mean absolute error (eq. 14) against the initial poses [%]."""
        return reduction_percent(self.stats_initial.mean_abs, self.stats.mean_abs)

    @property
    def std_reduction_percent(self):
        return reduction_percent(self.stats_initial.std_abs, self.stats.std_abs)

    def summary(self):
        """Plain-data figures (no per-position arrays)."""
        return {
            "channel": self.channel, "positions": self.position_count, "groove_positions": self.groove_count,
            "line_count": self.line_count, "line_count_value": self.line_count_value,
            "line_spacing_mm": self.line_spacing, "machining_length_mm": self.machining_length,
            "l_min_mm": self.l_min, "r_max_mm": self.r_max, "tool_radius_mm": self.tool_radius,
            "stats_initial": self.stats_initial.to_dict(), "stats_paper": self.stats_paper.to_dict(),
            "stats": self.stats.to_dict(), "mae_reduction_percent": self.mae_reduction_percent,
            "mae_reduction_percent_paper_iteration": reduction_percent(self.stats_initial.mean_abs,
                                                                       self.stats_paper.mean_abs),
            "paper_mae_reduction_percent": PAPER_MAE_REDUCTION_PERCENT,
            "hausdorff_mean_mm": {"initial": float(self.hausdorff_initial.mean()),
                                  "paper": float(self.hausdorff_paper.mean()), "final": float(self.hausdorff.mean())},
            "secondary_positions": int(self.secondary.sum()),
            "iterations_mean": float(self.iterations.mean()),
            "polish_iterations_mean": float(self.polish_iterations.mean()),
            "path_samples": len(self.samples), "planning_time_s": self.planning_time,
            "options": self.options.to_dict(),
        }


def roughing_plan_id(geometry_id, channel, options):
    """A deterministic id of a roughing request (the planner is deterministic): equal requests, equal ids."""
    key = json.dumps(["plunge_roughing", geometry_id, int(channel), options.to_dict()], sort_keys=True, default=str)
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def target_surface(blisk, allowance):
    """The target surface's profile: the shroud offset by the allowance towards the axis (RevolutionProfile)."""
    return blisk.shroud.offset(-allowance, *blisk.shroud.x_range)


def _report(progress, stage, fraction, nodes=0, reference=0.0, message=""):
    if progress is not None:
        progress(stage, float(fraction), int(nodes), float(reference), message)


def _retract_distance(point, axis, hub, clearance, limit):
    """Distance along the tool axis that takes the bottom centre ``clearance`` below the hub radius."""
    def below(L):
        p = point + L * axis
        return float(np.hypot(p[1], p[2]) - (hub.radius_at(p[0]) - clearance))

    if below(0.0) <= 0:
        return 0.0
    if below(limit) > 0:
        raise EdmError(ErrorCode.INFEASIBLE, f"no retract point within {limit:.1f} mm along the tool axis "
                                             "clears the hub radius; give retract_height")
    return brentq(below, 0.0, limit, xtol=1e-9)


def check_travel(samples, axis_names, machine):
    """INFEASIBLE naming axis, joint, value and sample if an axis value leaves the machine's travel.

    Parameters
    ----------
    samples : (N, k) float
        Planner axis values [mm, rad].
    axis_names : sequence of str
    machine : MachineConfig
        Its axes must be exactly ``axis_names`` (INVALID_REQUEST otherwise).
    """
    for lim, j in zip(machine.limits_for(axis_names), range(len(axis_names))):
        joint = lim.to_joint(samples[:, j])
        bad = np.flatnonzero((joint < lim.position_min) | (joint > lim.position_max))
        if len(bad):
            raise EdmError(ErrorCode.INFEASIBLE,
                           f"roughing path: axis {lim.name} (joint {lim.joint}) at {joint[bad[0]]:.6g} {lim.unit} "
                           f"leaves its travel [{lim.position_min:g}, {lim.position_max:g}] {lim.unit} at sample "
                           f"{bad[0]}")


def plan_roughing(blisk, channel=0, options=RoughingOptions(), progress=None, machine=None):
    """Plan the plunge roughing of the shroud's inner surface in one channel.

    Parameters
    ----------
    blisk : Blisk
        Or any object with a ``blisk`` attribute (a loaded geometry).
    channel : int
        0 .. N-1.
    options : RoughingOptions
    progress : callable, optional
        ``progress(stage, fraction, nodes, reference_mm, message)`` as the EDM planner's: stages
        'positions', 'optimise' (nodes = positions done, the message names the position and the
        mean Hausdorff distance so far; reference_mm is 0) and 'path'.
    machine : MachineConfig, optional
        If given, the path's axis values are checked against its travel (:func:`check_travel`).

    Returns
    -------
    RoughingResult

    Raises
    ------
    EdmError
        INVALID_REQUEST: bad channel or options. INFEASIBLE: r_max <= 0, a requested tool radius
        above r_max, a channel too narrow for the tool, an optimised pose that still cuts into the
        finished shroud (Hausdorff distance above the allowance), a path outside the machine's travel.
    """
    t0 = time.perf_counter()
    blisk = getattr(blisk, "blisk", blisk)
    if not isinstance(options, RoughingOptions):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"options must be RoughingOptions, got {type(options).__name__}")
    n_blades = blisk.blade_count
    if isinstance(channel, bool) or not isinstance(channel, (int, np.integer)) or not 0 <= channel < n_blades:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"channel must be an integer in [0, {n_blades - 1}], got {channel!r}")
    channel = int(channel)
    o = options
    _report(progress, "positions", 0.0, message="blade gap and tool radius (eq. 10-11)")

    # eq. 10-11
    _, radii, thickness = blade_root_data(blisk, o.root_points)
    l_min = minimum_gap(radii, thickness, n_blades)
    r_max = max_tool_radius(l_min, o.allowance, o.mu)
    if r_max <= 0:
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"no tool fits: r_max = (L_min - 2 delta) / (2 mu) = ({l_min:.4f} - 2 x {o.allowance:g}) / "
                       f"(2 x {o.mu:g}) = {r_max:.4f} mm (eq. 11); reduce the allowance or mu")
    radius = r_max if o.tool_radius is None else float(o.tool_radius)
    if radius > r_max * (1 + 1e-12):
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"tool radius {radius:g} mm exceeds r_max = {r_max:.4f} mm (eq. 11: L_min {l_min:.4f} mm, "
                       f"allowance {o.allowance:g} mm, mu {o.mu:g})")

    # target surface and positions (channel 0)
    target = target_surface(blisk, o.allowance)
    pos = plan_positions(blisk, target, radius, o.allowance, o.residual_height, o.step_tolerance, o.max_step,
                         o.lateral_step)
    area = pos.area
    mid = len(area.m) // 2
    theta_c = 0.5 * (area.theta_suction[mid] + area.theta_pressure[mid])
    x_ref = float(area.x[mid])
    reference = reference_pose(theta_c, x_ref, float(target.radius_at(x_ref)))
    a_near = channel * blisk.pitch
    theta = pos.theta + channel * blisk.pitch
    r = np.hypot(pos.points[:, 1], pos.points[:, 2])
    points = np.column_stack([pos.x, r * np.cos(theta), r * np.sin(theta)])
    radial_in = -np.column_stack([np.zeros_like(theta), np.cos(theta), np.sin(theta)])
    initial = tool_poses(points, radial_in, reference, a_near)
    n = len(points)
    _report(progress, "positions", 1.0, n, 0.0, f"{n} positions: {pos.groove_count} grooving, "
                                                f"{pos.line_count} expansion lines")

    # pose optimisation
    dist = RevolutionDistance(target)
    bottom = bottom_points(radius, o.bottom_rings, o.bottom_points)
    poses = np.empty_like(initial)
    h0, hp, h = (np.empty(n) for _ in range(3))
    err0, errp, err = (np.empty((n, len(bottom))) for _ in range(3))
    iters, piters = np.zeros(n, dtype=int), np.zeros(n, dtype=int)
    secondary = np.zeros(n, dtype=bool)
    for k, i in enumerate(pos.order):
        model = ToolPoseModel(dist, initial[i], bottom, radius)
        opt = optimise_pose(model, o.rotation_range, o.translation_range, o.secondary_rotation_range, o.eta,
                            o.increment_tolerance, o.objective_tolerance, o.max_iterations, o.polish)
        # the machine's frame about the (unchanged) optimised axis and bottom centre
        poses[i] = tool_poses(opt.pose[None, :3, 3], opt.pose[None, :3, 2], reference, a_near)[0]
        err0[i] = model.errors(np.zeros(3))
        errp[i] = model.errors(opt.x_paper)
        final = ToolPoseModel(dist, poses[i], bottom, radius)
        err[i] = final.errors(np.zeros(3))
        h0[i], hp[i], h[i] = np.abs(err0[i]).max(), np.abs(errp[i]).max(), np.abs(err[i]).max()
        iters[i], piters[i], secondary[i] = opt.iterations, opt.polish_iterations, opt.secondary
        if h[i] > o.allowance:
            raise EdmError(ErrorCode.INFEASIBLE,
                           f"position {pos.labels[i]}: the best flat-bottom pose deviates {h[i]:.4f} mm from the "
                           f"target surface, more than the allowance {o.allowance:g} mm: it would cut into the "
                           "finished shroud; choose a smaller tool radius or a larger allowance")
        _report(progress, "optimise", (k + 1) / n, k + 1, 0.0,
                f"{pos.labels[i]}, mean Hausdorff distance so far {h[pos.order[:k + 1]].mean():.5f} mm")

    # the axis path in travel order
    _report(progress, "path", 0.0, n, 0.0, "axis path")
    order = pos.order
    bottom_q = axes_for(poses[order, :3, 3], poses[order, :3, 2], reference, a_near)
    if o.retract_height is not None:
        retract = np.full(n, float(o.retract_height))
    else:
        height = blisk.channel_height_range[1]
        retract = np.array([_retract_distance(poses[i, :3, 3], poses[i, :3, 2], blisk.hub, o.retract_clearance,
                                              5.0 * height + o.retract_clearance + 10.0) for i in order])
    path = plunge_path(bottom_q, retract, reference, radius, o.path_spacing)
    if machine is not None:
        check_travel(path.samples, path.axis_names, machine)
    _report(progress, "path", 1.0, n, 0.0, f"{len(path.samples)} samples")

    return RoughingResult(
        channel=channel, options=o, l_min=l_min, r_max=r_max, tool_radius=radius, labels=pos.labels, order=order,
        poses=poses, initial_poses=initial, hausdorff_initial=h0, hausdorff_paper=hp, hausdorff=h,
        errors_initial=err0, errors=err, stats_initial=error_stats(err0), stats_paper=error_stats(errp),
        stats=error_stats(err), iterations=iters, polish_iterations=piters, secondary=secondary,
        line_count=pos.line_count, line_count_value=pos.line_count_value, groove_count=pos.groove_count,
        line_spacing=pos.line_spacing, groove_steps=pos.groove_steps, machining_length=area.length,
        axis_names=path.axis_names, samples=path.samples, reference_pose=path.reference_pose,
        bottom_index=path.bottom_index, retract_distances=path.retract_distances,
        planning_time=time.perf_counter() - t0, path=path)
