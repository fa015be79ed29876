"""Plan one channel: exit search, C2 spline fit, continuous certification, electrode sizing.

The pipeline (Huang III-IV, Liu 4.1-4.2):

1. the backward exit search (:mod:`.search`) from the final machining pose
   out of channel 0, both axial sides unless one is asked for;
2. the nodes, reversed into feed order, turned into machine axis values and
   smoothed (per-axis smoothing spline, GCV weight) and interpolated by a C2
   cubic spline through the exact machining pose;
3. the spline sampled so densely that no electrode vertex moves more than the
   sample spacing between samples and certified interval by interval
   (:mod:`.certify`); where it fails the smoothing is reduced, down to the
   raw nodes; a plan that is not certified is never a success;
4. the plan moved to channel k by A = k * pitch (the blisk is periodic).

With ``size_electrode`` the circumferential reduction h is bisected for the
smallest value (thickest electrode) that still gives a certified plan.
"""

import functools
import hashlib
import json
import logging
from dataclasses import asdict, replace

import numpy as np
from scipy.interpolate import CubicSpline

from ..budget import budget_clock
from ..errors import EdmError, ErrorCode
from ..geometry.centerline import channel_centerline
from ..geometry.electrode import design_electrodes
from ..geometry.electrode_cache import cached_design
from ..geometry.frames import rotation_about_x
from ..interference import SURFACES
from ..interference.fast import FastChannelField
from ..interference.pose_check import verify_poses
from ..cnc.kinematics import axis_poses, state_axes
from .certify import AGREEMENT_ACCURACY, PathCertifier
from .plan import AXIS_NAMES, Plan, PlanMetrics, PlanOptions
from .search import ExitSearch, SearchStatus
from .smoothing import SmoothingBasis

_log = logging.getLogger(__name__)

#: smoothing levels tried in turn: multiples of the GCV weight, 0 = the raw nodes
SMOOTHING_LEVELS = (1.0, 0.1, 0.01, 0.0)


def plan_id_for(geometry_id, channel, electrode_id, options, design=None):
    """A deterministic id of a request: equal requests give equal plans (the search is seeded)."""
    key = json.dumps([geometry_id, int(channel), electrode_id, asdict(options),
                      None if design is None else asdict(design)], sort_keys=True, default=str)
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def _node_axes(electrode, states, axes):
    """Machine axis values of search states (exit order in, same order out)."""
    pos = states[:, :3]
    if axes == 4:
        q = state_axes(electrode.final_pose, pos, np.zeros(len(states)), states[:, 3])
        return q[:, [0, 1, 2, 4]]
    b = states[:, 5] if axes == 6 else None
    return state_axes(electrode.final_pose, pos, states[:, 3], states[:, 4], b)


@functools.lru_cache(maxsize=4)
def _smoothing_basis(params_bytes):
    """The Demmler-Reinsch basis of a path's parameters (an eigendecomposition, ~0.15 s for 300 nodes), kept for
    the next smoothing levels of the same path."""
    return SmoothingBasis(np.frombuffer(params_bytes, dtype=np.float64))


def fit_path(params, nodes, level):
    """C2 cubic spline through (smoothed) nodes; the last node (the machining pose) is kept exactly.

    Parameters
    ----------
    params : (n,) float
        Increasing path parameters of the nodes [mm].
    nodes : (n, k) float
        Axis values, feed order.
    level : float
        Multiple of each axis' GCV smoothing weight; 0 interpolates the raw nodes.

    Returns
    -------
    scipy.interpolate.CubicSpline
    """
    values = nodes.copy()
    if level > 0 and len(params) >= 5:
        basis = None
        for j in range(nodes.shape[1]):
            y = nodes[:, j]
            if np.abs(np.diff(y, 2)).max(initial=0.0) <= 1e-12 * max(np.abs(y).max(), 1.0):
                continue                          # already straight (X along the X reference): nothing to smooth
            if basis is None:                     # one decomposition serves every axis, and every level
                basis = _smoothing_basis(np.ascontiguousarray(params, dtype=np.float64).tobytes())
            values[:, j] = basis.fit(y, basis.gcv_weight(y) * level)
        values[-1] = nodes[-1]
    return CubicSpline(params, values, bc_type="not-a-knot")


def smoothness_figures(values):
    """Per axis: sum of squared second differences and the count of velocity sign changes."""
    d1 = np.diff(values, axis=0)
    d2 = np.diff(values, n=2, axis=0)
    squared = (d2 ** 2).sum(axis=0)
    sharp = []
    for j in range(values.shape[1]):
        v = d1[:, j][np.abs(d1[:, j]) > 1e-9]             # standing still is not a reversal
        sharp.append(int(np.count_nonzero(np.diff(np.sign(v)))))
    return tuple(float(v) for v in squared), tuple(sharp)


def plan_channel(geometry, channel=0, electrode_id="", options=None, field=None, progress=None, design=None,
                 cache_dir=None, electrodes=None, exact_clearance=True):
    """Plan the feed path of one electrode into one channel.

    Parameters
    ----------
    geometry : LoadedGeometry
    channel : int
        0 .. blade_count - 1.
    electrode_id : str
        '' for the geometry's first electrode.
    options : PlanOptions
    field : FastChannelField, optional
        Built (and cached under ``cache_dir``) when not given.
    progress : callable, optional
        ``progress(stage, fraction, nodes, reference_mm, message)``.
    design : ElectrodeDesign, optional
        Re-design the electrodes with this design instead of the geometry's.
    electrodes : list of Electrode, optional
        The electrodes of ``design``, already designed (callers that plan one design repeatedly).
    exact_clearance : bool
        Also find the exact minimum clearance over the plan's samples
        (:func:`add_exact_clearance`, about 0.6 s) for ``metrics.clearance_exact``.

    Returns
    -------
    Plan
        ``error_code`` SUCCESS only for a certified plan.

    Raises
    ------
    EdmError
        INVALID_REQUEST for a bad channel, UNKNOWN_ID for an unknown electrode.
    """
    t0 = budget_clock()
    options = options or PlanOptions()
    if not (isinstance(channel, (int, np.integer)) and 0 <= channel < geometry.blisk.blade_count):
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"channel must be an integer in 0 .. {geometry.blisk.blade_count - 1}, got {channel!r}")
    own = geometry.for_channel(channel)
    if own is not geometry:
        # a blisk as measured: the channel's own two blades; a field or electrodes of another blisk do not apply
        geometry, field = own, (field if field is not None and field.blisk is own.blisk else None)
        electrodes = None
    blisk = geometry.blisk
    if field is None:
        field = FastChannelField(blisk, spacing=0.1, cache_dir=cache_dir, cache_key=geometry.field_key)
    base_design = design or geometry.design
    if electrodes is None:
        electrodes = geometry.electrodes if design is None else cached_design(blisk, design, cache_dir=cache_dir)
    electrode = _pick(electrodes, electrode_id)
    if options.size_electrode:
        plan = _size(geometry, channel, electrode.electrode_id, options, field, progress, base_design, t0)
    else:
        # planning time: search, fit and certification (the field and the electrode exist by now)
        plan = _plan_one(geometry, channel, electrode, options, field, progress, base_design, budget_clock())
    if exact_clearance and plan.success:
        _report(progress, "exact", 0.0, plan.metrics.node_count, 0.0, "exact clearance over the plan's samples")
        add_exact_clearance(plan, blisk, field)
        _report(progress, "exact", 1.0, plan.metrics.node_count, 0.0,
                f"exact minimum clearance {min(plan.metrics.clearance_exact):.4f} mm")
    return plan


def add_exact_clearance(plan, blisk, field=None):
    """Fill ``plan.metrics.clearance_exact``: the exact minimum signed clearance of every electrode vertex
    at every sample of a certified plan, per surface (:func:`~..interference.pose_check.verify_poses`).

    Returns the :class:`~..interference.pose_check.PoseCheck`.
    """
    check = verify_poses(plan.poses, plan.electrode_mesh.vertices, plan.channel, blisk, field,
                         faces=plan.electrode_mesh.faces)
    m = plan.metrics
    m.clearance_exact = tuple(float(check.clearance_exact[s]) for s in SURFACES)
    plan.message += f"; exact minimum clearance {min(m.clearance_exact):.4f} mm"
    # one truth: a measurement at the plan's own samples never lies below a sound bound of the whole path
    wrong = [f"{s} {e:.4f} mm against the certified {b:.4f} mm"
             for s, e, b in zip(SURFACES, m.clearance_exact, m.clearance_lower_bound)
             if np.isfinite(b) and e < b - AGREEMENT_ACCURACY]
    if wrong:
        plan.error_code = ErrorCode.NOT_CERTIFIED
        plan.message = ("the certificate and the exact re-check disagree (" + "; ".join(wrong) +
                        "): the plan is not delivered; " + plan.message)
        _log.error("plan %s: %s", plan.plan_id, plan.message)
    _log.info("plan %s: clearance lower bound %.4f mm (certified), exact minimum %.4f mm (%d samples x %d "
              "vertices, %.2f s)", plan.plan_id, min(m.clearance_lower_bound), min(m.clearance_exact),
              check.samples, check.vertices, check.elapsed)
    return check


def _pick(electrodes, electrode_id):
    if not electrode_id:
        return electrodes[0]
    for e in electrodes:
        if e.electrode_id == electrode_id:
            return e
    raise EdmError(ErrorCode.UNKNOWN_ID, f"no electrode {electrode_id!r}; this design has "
                                         f"{[e.electrode_id for e in electrodes]}")


def _report(progress, stage, fraction, nodes=0, reference=0.0, message=""):
    if progress is not None:
        progress(stage, float(fraction), int(nodes), float(reference), message)


def _plan_one(geometry, channel, electrode, options, field, progress, design, t0, time_budget=None):
    so = options.search
    blisk = geometry.blisk
    axis_names = AXIS_NAMES[so.axes]
    budget = so.time_budget if time_budget is None else time_budget
    pid = plan_id_for(geometry.geometry_id, channel, electrode.electrode_id, options, design)
    search_opts = replace(so, time_budget=max(budget - (budget_clock() - t0), 1e-3))
    centerline = channel_centerline(blisk) if so.reference == "centerline" else None
    search = ExitSearch(blisk, electrode, field, search_opts, centerline=centerline)

    def on_search(fraction, nodes, reference):
        _report(progress, "search", fraction, nodes, reference)

    res = search.run(progress=on_search)
    metrics = PlanMetrics(axis_names=axis_names, solver_evaluations=res.evaluations,
                          circumferential_reduction=float(design.circumferential_reduction),
                          objfun1=float(res.objfun1), objfun2=float(res.objfun2), node_count=len(res.states))

    def failed(code, message, **extra):
        metrics.planning_time = budget_clock() - t0
        empty = np.zeros((0, len(axis_names)))
        fields = dict(furthest_node=max(len(res.states) - 1, 0), furthest_reference=float(res.furthest_reference),
                      blocking_surface=res.blocking_surface,
                      blocking_clearance_lower_bound=float(res.blocking_clearance_lower_bound))
        fields.update(extra)
        return Plan(pid, code, message, geometry.geometry_id, channel, electrode.electrode_id, electrode.mesh,
                    electrode.final_pose, options, axis_names, empty, np.zeros((0, 4, 4)), empty, metrics, **fields)

    if res.status != SearchStatus.SUCCESS:
        return failed(res.status.error_code, res.message)
    nodes = _node_axes(electrode, res.states[::-1], so.axes)          # feed order
    # the path parameter: distance along the reference (Huang's x_i, Liu's s), 0 at the start outside
    params = res.reference[-1] - res.reference[::-1]
    keep = np.concatenate([[True], np.diff(params) > 1e-9])
    params, nodes = params[keep], nodes[keep]
    margins = np.array([so.margin_blade, so.margin_blade, so.margin_hub_shroud, so.margin_hub_shroud])
    certifier = PathCertifier(field, electrode.mesh.vertices, lambda q: axis_poses(electrode.final_pose, axis_names, q),
                              axis_names, margins, electrode.final_pose[:3, 3],
                              allowance=float(getattr(design, "chord_tolerance", 0.0)),
                              faces=electrode.mesh.faces)
    cert = None
    for i, level in enumerate(SMOOTHING_LEVELS):
        if budget_clock() - t0 > budget:
            return failed(ErrorCode.TIMEOUT, f"time budget of {budget:g} s used up while certifying the path")
        _report(progress, "certify", i / len(SMOOTHING_LEVELS), len(nodes), params[-1],
                f"smoothing level {level:g}")
        spline = fit_path(params, nodes, level)
        cert = certifier.certify(spline, params[0], params[-1])
        if cert.certified:
            break
        _log.info("smoothing level %g: certification fails at %.3f mm (%s, %.4f mm below the margin)",
                  level, cert.first_failure, cert.failure_surface, cert.penetration_bound)
    if not cert.certified:
        return failed(ErrorCode.INFEASIBLE,
                      f"the path cannot be certified: at {cert.first_failure:.3f} mm along the feed path the "
                      f"{cert.failure_surface} clearance may fall {cert.penetration_bound:.4f} mm below its "
                      f"margin even through the raw search nodes", blocking_surface=cert.failure_surface,
                      blocking_clearance_lower_bound=float(
                          margins[SURFACES.index(cert.failure_surface)] - cert.penetration_bound))
    dense, _ = certifier.sample(spline, params[0], params[-1], options.sample_spacing)
    samples = spline(dense)
    samples[-1] = nodes[-1]                                            # exactly the machining pose
    poses = axis_poses(electrode.final_pose, axis_names, samples)
    metrics.path_length = float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum())
    if channel:
        if "A" in axis_names:
            samples[:, axis_names.index("A")] += channel * blisk.pitch
        poses = rotation_about_x(channel * blisk.pitch)[None] @ poses
    sm, sharp = smoothness_figures(spline(params))
    metrics.clearance_lower_bound = tuple(float(v) for v in cert.lower_bound)
    metrics.smoothness, metrics.sharp_points = sm, sharp
    metrics.certified = True
    metrics.planning_time = budget_clock() - t0
    _report(progress, "certify", 1.0, len(nodes), params[-1], "certified")
    return Plan(pid, ErrorCode.SUCCESS,
                f"certified path of {len(samples)} samples, {len(nodes)} nodes, exit "
                f"{'downstream' if res.direction > 0 else 'upstream'}; clearance lower bound "
                f"{min(metrics.clearance_lower_bound):.4f} mm (certified)", geometry.geometry_id, channel, electrode.electrode_id,
                electrode.mesh, electrode.final_pose, options, axis_names, samples, poses, nodes, metrics)


def _size(geometry, channel, electrode_id, options, field, progress, design, t0):
    """Bisect the circumferential reduction h for the thickest electrode with a certified plan."""
    blisk = geometry.blisk
    budget = options.search.time_budget
    plain = replace(options, size_electrode=False)
    tried = {}

    def attempt(h):
        d = replace(design, circumferential_reduction=float(h))
        electrode = _pick(design_electrodes(blisk, d), electrode_id)
        _report(progress, "sizing", min((budget_clock() - t0) / budget, 0.99), 0, 0.0,
                f"trying h = {h:.4f} rad")
        plan = _plan_one(geometry, channel, electrode, plain, field, None, d, t0, time_budget=budget)
        tried[h] = plan
        return plan

    # the largest sensible reduction: an electrode a tenth of the narrowest channel angle thick
    h_max = 0.9 * float(np.min((blisk.pitch - (blisk.blade.theta_plus - blisk.blade.theta_minus))))
    hi = float(design.circumferential_reduction) if design.circumferential_reduction > 0 else 0.5 * h_max
    plan = attempt(hi)
    while not plan.success and hi < h_max and plan.error_code != ErrorCode.TIMEOUT:
        hi = min(2.0 * hi, h_max)
        plan = attempt(hi)
    if not plan.success:
        plan.message = f"no certified path up to a circumferential reduction of {hi:.4f} rad: {plan.message}"
        return plan
    best, lo = plan, 0.0
    if 0.0 not in tried:
        p0 = attempt(0.0)
        if p0.success:
            best, hi = p0, 0.0
    while hi - lo > options.sizing_tolerance and budget_clock() - t0 < budget:
        mid = 0.5 * (lo + hi)
        p = attempt(mid)
        if p.success:
            best, hi = p, mid
        elif p.error_code == ErrorCode.TIMEOUT:
            break
        else:
            lo = mid
    best.metrics.planning_time = budget_clock() - t0
    best.message = (f"smallest circumferential reduction with a certified path: {hi:.4f} rad "
                    f"(infeasible at {lo:.4f} rad, {len(tried)} plans); " + best.message)
    _report(progress, "sizing", 1.0, best.metrics.node_count, 0.0, best.message)
    return best
