"""Roughing electrodes: each piece of a set gets a thinner twin that runs first, at the rough regime.

Shops rough with a large spark gap at high energy and finish with a small gap at low energy. The roughing
electrode of a piece is the piece's own design (same split, same reductions) with its faces offset from the
walls by the rough spark gap plus the finishing allowance instead of the finish gap, and its cut faces (axial
ends, split faces) drawn in by as much (:func:`twin_design`): it lies that far inside its finishing
electrode all round. Eroding with the rough gap it leaves the allowance on every wall, which the finishing
electrode (today's electrode, unchanged) then takes to size.

It follows the finishing electrode's feed, re-certified with the roughing electrode (its own certificate,
not inferred from the thicker twin's) with the rough spark gap less the tolerance as margin (no overcut),
and its own copy-processing legs built and certified by :class:`~.cycle.CycleBuilder` with its offset less
the tolerance as margin (they keep the allowance too), so it never erodes into a final surface beyond
the tolerance. The roughing proof
(:func:`~.removal.simulate_removal` with the rough gap) then shows the allowance it leaves: per wall sample
the stock, which should lie within allowance +- band wherever the finishing proof reaches the tolerance.
No rclpy.
"""

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import EdmError, ErrorCode
from ..geometry.electrode import Electrode, design_electrodes
from ..cnc.kinematics import axis_poses
from ..planning.certify import PathCertifier
from .cycle import CycleBuilder
from .mesh_distance import MeshDistance
from .proof_path import proof_samples
from .swept_stock import Sweep


@dataclass
class RoughPiece:
    """The roughing twin of one piece: design, electrode, certified cycle and the allowance it leaves."""

    label: str
    electrode_id: str
    design: object
    electrode: object
    cycle: object
    feed_clearance: np.ndarray        # (4,) certified lower bound along the feed [mm]
    inset: float = float("nan")       # how deep the twin lies inside its finishing electrode, least [mm]

    @property
    def certified(self):
        return bool(self.cycle.certified)


def feed_spline(samples):
    """The clamped cubic through the feed samples on their chord-length parameter (what the timing runs)."""
    s = np.asarray(samples, dtype=np.float64)
    params = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(s, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(params) > 1e-12])
    return CubicSpline(params[keep], s[keep], bc_type="clamped"), params[keep]


def twin_design(design, process):
    """The roughing twin's design: every face offset from the walls by the rough gap plus the allowance
    instead of the finish gap, and the axial ends (cut planes, which no gap offsets) drawn in by the same
    extra offset, so that the twin lies that far inside its finishing electrode all round."""
    extra = float(process.rough_electrode_gap) - float(design.discharge_gap)
    axial = design.axial_range
    if axial is not None:
        axial = (float(axial[0]) + extra, float(axial[1]) - extra)
    # a split piece's cut face comes in by the extra offset too, along its normal: a front/rear cut plane
    # (x = split +- overlap / 2) along X; a left/right split face, inclined to the arc on a twisted channel,
    # by the design's split_inset (geometry.electrode._split_sides)
    if design.split == "front_rear":
        return replace(design, discharge_gap=float(process.rough_electrode_gap), axial_range=axial,
                       split_overlap=max(0.0, float(design.split_overlap) - 2.0 * extra))
    return replace(design, discharge_gap=float(process.rough_electrode_gap), axial_range=axial,
                   split_inset=extra if design.split == "left_right" else 0.0)


def axial_extent(design, electrode_id):
    """(x_start, x_end) [mm] of one electrode of a design (its axial range, or its part of a front/rear
    split, as :func:`~edm_planner.geometry.electrode.design_electrodes` cuts it); None without a range."""
    if design.axial_range is None:
        return None
    x0, x1 = (float(v) for v in design.axial_range)
    if design.split == "front_rear":
        xs = x0 + design.split_fraction * (x1 - x0)
        half = 0.5 * design.split_overlap
        return (x0, xs + half) if electrode_id == "front" else (xs - half, x1)
    return x0, x1


def in_frame_of(electrode, final_pose):
    """The electrode expressed in another electrode frame (given by its final pose): the same solid in W.

    A design's frame follows its own offset walls, so the twin's differs from its finishing electrode's;
    the twin follows the finishing electrode's axis values, which mean poses of that frame.
    """
    if np.array_equal(electrode.final_pose, final_pose):
        return electrode
    change = np.linalg.inv(final_pose) @ electrode.final_pose          # twin frame -> finishing frame
    mesh = electrode.mesh.copy()
    mesh.apply_transform(change)
    samples = {k: v @ change[:3, :3].T + change[:3, 3] for k, v in electrode.samples.items()}
    return Electrode(electrode.electrode_id, mesh, final_pose.copy(), samples)


def rough_piece(blisk, field, piece, process, cycle_options, walls_cache=None):
    """Design, plan and certify the roughing twin of a sized piece (its plan and cycle set).

    Parameters
    ----------
    blisk : Blisk
    field : FastChannelField
    piece : electrode_set.Piece
        Sized: ``design``, ``plan`` (channel 0) and ``cycle``.
    process : ProcessModel
    cycle_options : CycleOptions

    Returns
    -------
    RoughPiece
        ``cycle.certified`` False (with its message) when the feed or a leg cannot be certified.
    """
    design = twin_design(piece.design, process)
    found = [e for e in design_electrodes(blisk, design, only=piece.electrode_id, walls_cache=walls_cache)
             if e.electrode_id == piece.electrode_id]
    if not found:
        raise EdmError(ErrorCode.INTERNAL, f"no roughing electrode {piece.electrode_id!r} in its own design")
    plan = piece.plan
    electrode = in_frame_of(found[0], np.asarray(plan.final_pose, dtype=np.float64))
    # measured, not assumed: a left/right split face is drawn in along the arc, which on a twisted channel's
    # inclined split surface is less than the extra offset along its normal
    inside = MeshDistance(np.asarray(plan.electrode_mesh.vertices), np.asarray(plan.electrode_mesh.faces))
    inset = float(-inside(np.asarray(electrode.mesh.vertices)).max())
    names = tuple(plan.axis_names)
    feed = np.asarray(plan.samples, dtype=np.float64)
    builder = CycleBuilder(field, electrode, design, names, cycle_options)
    # the feed: no overcut (the rough gap less the tolerance); the process legs keep the allowance too
    # (the builder's margin: the twin's offset less the tolerance)
    safe = float(process.rough.spark_gap) - cycle_options.tolerance
    feed_certifier = PathCertifier(
        field, electrode.mesh.vertices, lambda q: axis_poses(electrode.final_pose, names, q), names,
        np.full(4, safe), electrode.final_pose[:3, 3], allowance=float(design.chord_tolerance),
        faces=electrode.mesh.faces)
    spline, params = feed_spline(feed)
    cert = feed_certifier.certify(spline, params[0], params[-1])
    cycle = builder.build(feed, safe if cert.certified else -np.inf, cert.lower_bound, required_feed_margin=safe)
    if not cert.certified:
        cycle.certified = False
        cycle.message = (f"the feed with the roughing electrode is not certified: at {cert.first_failure:.3f} of "
                         f"the path the {cert.failure_surface} clearance may fall below {safe:.3f} mm (the rough "
                         f"spark gap less the tolerance); " + cycle.message)
    return RoughPiece(f"rough-{piece.label}", piece.electrode_id, design, electrode, cycle,
                      np.asarray(cert.lower_bound, dtype=np.float64), inset)


def rough_sweeps(pieces):
    """A removal Sweep per roughing piece: its cycle's poses that retrace none (as the finishing proof)."""
    out = []
    for rp in pieces:
        samples, breaks = proof_samples(rp.cycle)
        poses = axis_poses(rp.electrode.final_pose, rp.cycle.axis_names, samples)
        mesh = rp.electrode.mesh
        out.append(Sweep(np.asarray(mesh.vertices), np.asarray(mesh.faces), poses, breaks))
    return out


def allowance_figures(rough_report, finish_report, process, tolerance, twinned=None, corner=None, ends=(),
                      samples=None):
    """How uniform the allowance the roughing electrodes leave is, per wall (mm, shares of the sampled area).

    The ideal twin (the channel shrunk by its offset G = rough gap + allowance a, eroding the rough gap)
    leaves a on the flat walls and more in the concave corners, where its rounding radius is G instead of
    the finish gap: stock_ideal = a + corner(G) (``corner``: :func:`~.corner_rounding.corner_rounding_stock` at G,
    from the walls alone). The allowance is judged against that, where the finishing proof reaches the
    tolerance with a finishing electrode that has a twin (``twinned``: indices of the finishing sweeps
    with one; None: all), away from the twins' axial ends (``ends``, x [mm]: within the twin's offset plus
    the extra offset of an end the walls keep more stock, which the finishing electrode takes): uniform
    when |stock - stock_ideal| <= band on >= 99 % of that area and nothing is overcut anywhere (stock >= 0).
    ``samples`` (:func:`~.wall_samples.wall_samples`) weights the shares by area; without, by sample count. Returns a dict per surface (the stock's min and max there, the
    largest allowance the finishing electrode meets, the share within the band, the smallest stock
    anywhere, the verdict) and for the set.
    """
    a, band = process.finish_allowance, process.allowance_band
    out = {}
    ok = True
    for name, rough in rough_report.surfaces.items():
        fin = finish_report.surfaces[name]
        rs, fs = np.asarray(rough.stock, float), np.asarray(fin.stock, float)
        ideal = a + (0.0 if corner is None else np.asarray(corner[name], float).reshape(rs.shape))
        valid = np.isfinite(rs) & np.isfinite(fs)
        where = valid & (np.abs(np.where(valid, fs, 0.0)) <= tolerance)
        if twinned is not None:
            where &= np.isin(np.asarray(fin.which)[..., 0], np.asarray(twinned, dtype=np.int64))
        strip = 2.0 * process.rough_electrode_gap - process.finish.spark_gap      # offset + extra offset
        for x in ends:                    # u is the axial position x on every wall map
            where &= np.abs(np.asarray(fin.u, float) - x) > strip
        within = where & (np.abs(np.where(valid, rs, 0.0) - ideal) <= band)
        w = (np.ones(rs.shape) if samples is None
             else np.asarray(samples[name].weights, float).reshape(rs.shape))          # area weights
        share = float(w[within].sum() / w[where].sum()) if where.any() and w[where].sum() > 0 else float("nan")
        overcut = float(np.nanmin(rs)) if valid.any() else float("nan")
        good = overcut >= 0.0 and (not where.any() or share >= 0.99)
        ok &= good
        out[name] = {"stock_min_mm": round(float(rs[where].min()), 4) if where.any() else None,
                     "stock_max_mm": round(float(rs[where].max()), 4) if where.any() else None,
                     "ideal_max_mm": round(float(np.max(np.broadcast_to(ideal, rs.shape)[where])), 4)
                     if where.any() else None,
                     "share_within_band": round(share, 4), "smallest_stock_mm": round(overcut, 4),
                     "uniform": bool(good)}
    return {"allowance_mm": a, "band_mm": band, "surfaces": out, "uniform": bool(ok),
            "twin_ends_x_mm": [round(float(x), 4) for x in ends],
            "what": f"roughing stock within {band:g} mm of the ideal twin's ({a:g} mm on the walls, more in the "
                    f"concave corners, rounded with the twin's offset {process.rough_electrode_gap:g} mm) on >= 99 % "
                    f"of the area the twinned finishing electrodes machine to the tolerance; no overcut "
                    f"(stock >= 0) anywhere"}
