"""The exact re-check of an exported plan directory (``edm-plan check``).

:func:`verify_exported_plan` reads a plan export (:mod:`.plan_export`: electrode.stl and the sample poses, not
the planner's objects), re-checks every electrode vertex at every sample exactly with
:func:`~edm_planner.interference.pose_check.verify_poses`, and checks the file's own promises: the vertex
step, the axis values against the poses, a start outside the blade row, the final pose. Used by
``edm-plan check``, the plan export's tests and the benchmarks. Units: mm, rad. No rclpy.
"""

import logging
import time
from dataclasses import dataclass

import trimesh

from ..errors import EdmError, ErrorCode
from ..interference.exact_points import transform_points
from ..interference.pose_check import box_error, verify_poses
from ..cnc.kinematics import axes_to_poses
from .plan_export import MAX_VERTEX_STEP, read_plan

_log = logging.getLogger(__name__)


@dataclass
class PlanCheck:
    """The exact re-check of an exported plan.

    Attributes
    ----------
    passed : bool
        Every sample clear by ``threshold`` on every surface, no vertex step above
        ``max_step``, axis values and poses agree.
    clearance_exact : dict
        Surface -> the smallest exact signed clearance over all samples and vertices [mm].
    argmin : dict
        Surface -> (sample, vertex) attaining it.
    max_vertex_step : float
        Largest move of any electrode vertex between consecutive samples [mm].
    axes_pose_error : float
        Largest distance between an electrode vertex placed by the axis values and by the pose [mm].
    start_outside : bool
        The first sample's electrode lies wholly beyond the blade's axial range.
    final_pose_error : float
        Largest vertex distance between the last sample and the final pose in the plan's channel [mm].
    samples, vertices : int
    full_evaluations : int
        Anchor samples at which every vertex's side of both walls was tested (:func:`verify_poses`).
    exact_evaluations : int
        Vertex positions evaluated exactly on at least one surface, in all (of samples * vertices).
    elapsed : float
        [s]
    message : str
    """

    passed: bool
    clearance_exact: dict
    argmin: dict
    max_vertex_step: float
    axes_pose_error: float
    start_outside: bool
    final_pose_error: float
    samples: int
    vertices: int
    full_evaluations: int
    exact_evaluations: int
    threshold: float
    elapsed: float
    message: str = ""



def verify_exported_plan(path, blisk, threshold=0.0, max_step=MAX_VERTEX_STEP, anchor_stride=256,
                         geometry_id=None, progress=None, field=None, cache_dir=None, anchor_travel=0.5,
                         field_key=None):
    """Re-check an export directory with the exact clearance of every electrode vertex at every sample.

    Reads electrode.stl and the sample poses (not the planner's objects) and
    finds the exact minimum signed clearance of the electrode vertices to the
    four surfaces of the plan's channel over all samples with
    :func:`verify_poses` (numba exact solvers, branch and bound on the
    1-Lipschitz distance: the exact minimum over every vertex at every sample,
    with the caveats given there); checks that the axis values reproduce the
    poses, that the path ends at the final pose in the plan's channel and
    starts outside the blisk, and the largest vertex step.

    Parameters
    ----------
    path : path
        Export directory.
    blisk : Blisk
        The geometry (its hash is not recomputed here; pass ``geometry_id`` to compare).
    threshold : float
        Smallest clearance accepted [mm].
    max_step : float
        Largest vertex move between consecutive samples accepted [mm].
    anchor_stride : int
        Most samples between anchors of the side tests (:func:`verify_poses`).
    geometry_id : str, optional
        Must equal the plan's geometry id when given.
    progress : callable, optional
        ``progress(stage, fraction, 0, 0.0, message)``, stages of :func:`verify_poses`.
    field : FastChannelField, optional
        For its exact solvers; built, or loaded from ``cache_dir`` (key: the plan's geometry id), when not
        given (about 6 s to build, 1 s to load).
    cache_dir : path, optional
    anchor_travel : float
        Largest vertex travel between anchors of the side tests [mm] (:func:`verify_poses`).
    field_key : str, optional
        The field's cache key when not the plan's geometry id (a channel's own geometry on a blisk as measured,
        ``LoadedGeometry.for_channel(channel).field_key``; ``blisk`` is then that geometry's).

    Returns
    -------
    PlanCheck

    Raises
    ------
    PlanFileError
        From :func:`read_plan`.
    EdmError
        UNKNOWN_ID when ``geometry_id`` is given and differs from the plan's.
    """
    t0 = time.perf_counter()
    plan = read_plan(path)
    if geometry_id is not None and geometry_id != plan.geometry_id:
        raise EdmError(ErrorCode.UNKNOWN_ID, f"{path}: plan is for geometry {plan.geometry_id[:12]}, "
                                             f"not {geometry_id[:12]}")
    V = plan.electrode_mesh.vertices
    P = plan.poses
    ch = plan.channel
    box = trimesh.bounds.corners(plan.electrode_mesh.bounds)

    # consistency of the file: axis values reproduce the poses, the path ends at the final pose
    axes_error = box_error(axes_to_poses(plan.axis_names, plan.axes, plan.final_pose, ch, blisk.pitch), P, box)
    final_error = box_error(P[-1:], (blisk.channel_transform(ch) @ plan.final_pose)[None], box)
    first = transform_points(P[:1], V)[0, :, 0]
    start_outside = bool(first.min() > blisk.axial_range[1] or first.max() < blisk.axial_range[0])

    check = verify_poses(P, V, ch, blisk, field, threshold=threshold, anchor_stride=anchor_stride,
                         anchor_travel=anchor_travel, faces=plan.electrode_mesh.faces,
                         cache_dir=cache_dir, cache_key=field_key or plan.geometry_id, progress=progress)
    problems = [] if check.passed else [check.message]
    if check.max_vertex_step > max_step + 1e-12:
        problems.append(f"a vertex moves {check.max_vertex_step:.4f} mm between samples (limit {max_step} mm)")
    if axes_error > 1e-6:
        problems.append(f"axis values and poses disagree by {axes_error:.3g} mm")
    if final_error > 1e-6:
        problems.append(f"the last sample is {final_error:.3g} mm from the final pose in channel {ch}")
    if not start_outside:
        problems.append("the first sample is not outside the blisk's axial range")
    elapsed = time.perf_counter() - t0
    _log.info("verified %s: %d samples x %d vertices, %d exact points (%s), %.1f s (search %.1f s)",
              path, check.samples, check.vertices, check.exact_evaluations, check.exact_by_surface, elapsed,
              check.elapsed)
    return PlanCheck(passed=not problems, clearance_exact=check.clearance_exact, argmin=check.argmin,
                     max_vertex_step=check.max_vertex_step, axes_pose_error=axes_error, start_outside=start_outside,
                     final_pose_error=final_error, samples=check.samples, vertices=check.vertices,
                     full_evaluations=check.anchor_samples, exact_evaluations=check.exact_evaluations,
                     threshold=float(threshold), elapsed=elapsed, message="; ".join(problems) or "ok")
