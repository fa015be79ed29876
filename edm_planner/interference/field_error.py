"""The fast field's measured error: sample points near the surfaces, the best known reference, the bounds.

At build, :class:`.fast.FastChannelField` answers random points within 2 mm
of channel 0's surfaces (both sides) and around the blade edges, and
anywhere in the grid, and compares with the best known exact distances
(:func:`reference_clearances`: ``ExactChannelDistance`` refined by the numba
solvers). The largest error times 1.5, plus the float32 quantisation, is
its ``error_bound`` (:func:`measure_error`). Units: mm, rad.
"""

import numpy as np

from . import SURFACES
from ..geometry.frames import cylindrical_to_cartesian
from .exact_points import ExactChannelDistance
from .field_params import ACCURATE_WITHIN


def error_sample_points(blisk, n=1500, seed=0):
    """Random points within 2 mm of channel 0's surfaces, for the error measurement.

    Per surface ``n`` points at -0.5 ... 2 mm from it (nominal; on both
    sides: a shallow penetration must be seen as well), spread over the
    channel, and ``n`` points within 2 mm of the leading and trailing
    edges of blades 0 and 1 (all around the edge).

    Returns
    -------
    (m, 3) float
        Points in W [mm].
    """
    b = blisk
    rng = np.random.default_rng(seed)
    x0, x1 = b.full_span_axial_range
    out = []
    x = rng.uniform(x0, x1, 4 * n)
    hub, shr = b.hub.radius_at(x), b.shroud.radius_at(x)
    r = hub + rng.uniform(0.02, 0.98, 4 * n) * (shr - hub)
    th_s, th_p, inside = b.wall_angles(x, r)
    delta = rng.uniform(-0.5, 2.0, 4 * n)
    frac = rng.uniform(0, 1, 4 * n)
    th_any = th_s + frac * (th_p - th_s)
    sl = [slice(k * n, (k + 1) * n) for k in range(4)]
    out.append(cylindrical_to_cartesian(x[sl[0]], r[sl[0]], th_s[sl[0]] + delta[sl[0]] / r[sl[0]]))
    out.append(cylindrical_to_cartesian(x[sl[1]], r[sl[1]], th_p[sl[1]] - delta[sl[1]] / r[sl[1]]))
    out.append(cylindrical_to_cartesian(x[sl[2]], hub[sl[2]] + delta[sl[2]], th_any[sl[2]]))
    out.append(cylindrical_to_cartesian(x[sl[3]], shr[sl[3]] - delta[sl[3]], th_any[sl[3]]))
    # around the edges: balls of 2 mm about the faces' leading and trailing edge lines
    v = rng.uniform(0.03, 0.97, n)
    u = rng.integers(0, 2, n).astype(float)
    edge = b.suction_face.surface.evaluate(u, v)
    ex, er, et = edge[:, 0], np.hypot(edge[:, 1], edge[:, 2]), np.arctan2(edge[:, 2], edge[:, 1])
    et = et + b.pitch * rng.integers(0, 2, n)          # blade 0 or blade 1
    d = rng.normal(size=(n, 3))
    d *= (rng.uniform(0, 1, n) ** (1 / 3) * 2.0 / np.linalg.norm(d, axis=1))[:, None]
    out.append(cylindrical_to_cartesian(ex, er, et) + d)
    return np.concatenate(out)


def reference_clearances(field, points, channel=0, exact=None):
    """The best known signed distances: ``ExactChannelDistance``, refined by the field's numba solvers.

    Every closest-point solver returns the distance to an actual surface
    point, an upper bound of the true distance; where a numba solver finds
    a closer point than the exact method (``BladeFace.closest_points`` can
    stop short of the minimum when the closest point lies on an edge of
    the face, ``ProfileDistance.signed`` when it lies on the kink at an end
    of the profile), its distance is taken, with the exact method's sign.

    Parameters
    ----------
    field : FastChannelField
    points : (n, 3) float
        [mm], in W.
    channel : int
    exact : ExactChannelDistance, optional

    Returns
    -------
    reference : (n, 4) float
        [mm], columns in the order of ``SURFACES``.
    exact : (n, 4) float
        ``ExactChannelDistance.clearances`` unchanged.
    """
    exact = exact or ExactChannelDistance(field.blisk)
    ref = exact.clearances(points, channel)
    mine = field._points(points, channel, 1)             # the numba blade and profile solvers, one pass
    closer = (np.abs(mine) < np.abs(ref)) & (np.sign(mine) == np.sign(ref))
    return np.where(closer, mine, ref), ref


def measure_error(field, n):
    """The field's error figures, measured near the surfaces and (for the far-field figure) anywhere in the grid.

    Returns
    -------
    dict
        ``error_bound``, ``far_error_bound``, ``measured_max_error``,
        ``error_sample_count`` and ``exact_method_excess``: the attributes of
        :class:`.fast.FastChannelField` of those names.
    """
    (x0, x1), (r0, r1), (t0, t1) = field.grid_bounds
    rng = np.random.default_rng(1)
    anywhere = cylindrical_to_cartesian(rng.uniform(x0, x1, n), rng.uniform(r0, r1, n), rng.uniform(t0, t1, n))
    pts = np.concatenate([error_sample_points(field.blisk, n), anywhere])
    ref, raw = reference_clearances(field, pts)
    got = field.clearances(pts)
    err = np.abs(got - ref)
    # outside the grid the values are lower bounds by design, not approximations
    inside = field.inside_grid(pts)[:, None]
    far = (np.abs(ref) > ACCURATE_WITHIN) & inside
    near = (np.abs(ref) <= ACCURATE_WITHIN) & inside
    measured = {name: float(err[near[:, k], k].max(initial=0.0)) for k, name in enumerate(SURFACES)}
    # float32 storage: half an ulp of the largest stored value within the band
    quantum = float(np.spacing(np.float32(ACCURATE_WITHIN + 1.0))) / 2
    return {
        "far_error_bound": 1.5 * float(err[far].max(initial=0.0)),
        "measured_max_error": measured,
        "error_sample_count": {name: int(near[:, k].sum()) for k, name in enumerate(SURFACES)},
        # how far BladeFace.closest_points stopped short of the minimum on these points (for the record)
        "exact_method_excess": float(np.abs(raw - ref)[near].max(initial=0.0)),
        "error_bound": 1.5 * max(measured.values()) + quantum,
    }
