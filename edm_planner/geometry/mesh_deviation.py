"""How far a channel's surface meshes deviate from the true surfaces, by side.

The workpiece meshes of :meth:`Blisk.channel_meshes` interpolate the true
surfaces (the bicubic blade faces, the hub and shroud of revolution) at their
vertices and cut across them in between: on a face that is concave seen from
the channel the chords lie in the channel, on a convex one in the material. A
clearance measured against the mesh is then off by up to that much, so the
deviation is stated per surface and per side:

* ``into_channel``: how far the mesh comes out of the true surface into the
  channel, towards the electrode (a clearance measured against the mesh can
  read too small by up to this);
* ``into_material``: how far the mesh lies behind the true surface, in the
  material (a clearance measured against the mesh can read too large by up to
  this).

Both are upper bounds, from samples plus a bound on what lies between them
(:func:`surface_deviation`). Units: mm.
"""

import logging
import pathlib
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import EdmError, ErrorCode
from .disk_cache import content_key, get_or_make_json
from .frames import rotation_about_x
from .spline_kernels import eval_many, kernel_net

_log = logging.getLogger(__name__)

#: samples per triangle edge: the remainder between samples is the triangle's sag over its square
SUBDIVISIONS = 8
#: largest distance [mm] between a mesh vertex (float64, before any rounding) and the true surface at its
#: parameters that is taken for the same point (the numba and scipy evaluators of one spline agree to ~1e-13)
VERTEX_TOLERANCE = 1e-8
#: what the figures are, for plan.json
KIND = "bound"
METHOD = ("per triangle: the true surface evaluated on a lattice of the triangle's parameter-space preimage "
          "(the mesh vertices are surface points at known parameters), signed distance of each sample to the "
          "triangle's plane (vertices as written), plus a bound on the linear-interpolation remainder between the "
          "samples: (A du^2 + 2 B du dv + C dv^2) / 8 over a lattice cell of parameter extents (du, dv), with "
          "A, B, C bounds on the second derivatives along the triangle's normal from the convex hulls of the "
          "spline's derivative control nets (blade faces) or of the profile's cubic pieces (hub, shroud)")
DEFINITION = {
    "into_channel": "largest distance [mm] by which the mesh lies on the channel side of the true surface, towards "
                    "the electrode: a clearance measured against the mesh reads too small by up to this",
    "into_material": "largest distance [mm] by which the mesh lies behind the true surface, in the material: a "
                     "clearance measured against the mesh reads too large by up to this",
}


@dataclass(frozen=True)
class SurfaceDeviation:
    """The deviation of one surface mesh from its true surface [mm].

    Attributes
    ----------
    into_channel, into_material : float
        Upper bounds (>= 0) of how far the mesh lies on the channel side of the
        true surface, and behind it in the material.
    measured_into_channel, measured_into_material : float
        The largest of the samples alone (each <= its bound).
    remainder : float
        The largest bound between samples added to a triangle's samples.
    at_into_channel, at_into_material : tuple of float
        The sample (a true surface point in W) behind each bound.
    subdivisions : int
        Samples per triangle edge.
    sample_spacing : float
        Largest distance between neighbouring samples, the longest mesh edge over ``subdivisions``.
    triangles : int
    """

    into_channel: float
    into_material: float
    measured_into_channel: float
    measured_into_material: float
    remainder: float
    at_into_channel: tuple
    at_into_material: tuple
    subdivisions: int
    sample_spacing: float
    triangles: int

    def to_dict(self):
        return asdict(self)


def lattice(n):
    """Barycentric weights of the points ``(i, j, n - i - j) / n`` of a triangle split into n^2: (m, 3)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    return np.column_stack([i, j, n - i - j]).astype(np.float64) / n


def plane_deviation(params, corners, normals, evaluate, hessian_bound, subdivisions=SUBDIVISIONS, chunk=4096):
    """Signed distances of true-surface samples to their triangles' planes, per triangle.

    Parameters
    ----------
    params : (T, 3, 2) float
        Surface parameters of each triangle's vertices (the preimage is the
        triangle they span in parameter space).
    corners : (T, 3, 3) float
        The triangles as written [mm].
    normals : (T, 3) float
        Unit normals of the triangles, pointing into the channel.
    evaluate : callable
        ``(n, 2) params -> (n, 3)`` true-surface points [mm].
    hessian_bound : callable
        ``(params (T, 3, 2), normals (T, 3)) -> A, B, C (T,)``: bounds of
        ``|n . S_aa|, |n . S_ab|, |n . S_bb|`` over each preimage.
    subdivisions : int
    chunk : int
        Triangles per evaluation batch (memory).

    Returns
    -------
    low, high : (T,) float
        Smallest and largest sample distance [mm] (positive: the surface is on
        the channel side of the plane).
    remainder : (T,) float
        Bound [mm] on how far the distance between samples goes beyond them.
    arg_low, arg_high : (T,) int
        Lattice index of the smallest and largest sample.
    """
    lam = lattice(subdivisions)
    T = len(params)
    low, high, arg_low, arg_high = np.empty(T), np.empty(T), np.empty(T, int), np.empty(T, int)
    for a in range(0, T, chunk):
        b = min(a + chunk, T)
        uv = lam @ params[a:b]                                        # (t, m, 2)
        pts = evaluate(uv.reshape(-1, 2)).reshape(b - a, len(lam), 3)
        g = ((pts - corners[a:b, None, 0]) @ normals[a:b, :, None])[..., 0]
        arg_low[a:b], arg_high[a:b] = g.argmin(axis=1), g.argmax(axis=1)
        low[a:b], high[a:b] = g.min(axis=1), g.max(axis=1)
    # every lattice cell is the triangle shrunk by 1/n (or point-reflected), so it has 1/n its extents
    w = np.ptp(params, axis=1) / subdivisions
    A, B, C = hessian_bound(params, normals)
    remainder = (A * w[:, 0] ** 2 + 2.0 * B * w[:, 0] * w[:, 1] + C * w[:, 1] ** 2) / 8.0
    return low, high, remainder, arg_low, arg_high


# -- the true surfaces -----------------------------------------------------------------------

def _derivative_coefficients(coef, knots, axis):
    """Control points of the derivative of a clamped B-spline along ``axis`` and its knots (degree - 1).

    ``d_i = p (c_{i+1} - c_i) / (t_{i+p+1} - t_{i+1})`` (Piegl & Tiller eq. 3.4 per direction).
    """
    p = len(knots) - coef.shape[axis] - 1
    c = np.moveaxis(coef, axis, 0)
    span = (knots[p + 1:-1] - knots[1:-p - 1]).reshape((-1,) + (1,) * (c.ndim - 1))
    return np.moveaxis(p * np.diff(c, axis=0) / span, 0, axis), knots[1:-1]


def _span(knots, n_ctrl, t):
    """Knot span of each t as ``spline_kernels.find_span`` (cubic: in [3, n_ctrl - 1])."""
    return np.clip(np.searchsorted(knots, t, side="right") - 1, 3, n_ctrl - 1)


class SplineFacePatch:
    """A bicubic face (``nurbs.SplineSurface``), optionally turned about X, as the true surface of a mesh.

    Parameters
    ----------
    surface : SplineSurface
    rotation : (3, 3) float, optional
        Face frame -> W (default: none).
    """

    def __init__(self, surface, rotation=None):
        self.rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        self._net = kernel_net(surface)
        cp, tu, tv = surface.control_points, surface.knots_u, surface.knots_v     # cp (nv, nu, 3)
        self._n = cp.shape[:2]
        self._knots = (tu, tv)
        du, tu1 = _derivative_coefficients(cp, tu, axis=1)
        dv, _ = _derivative_coefficients(cp, tv, axis=0)
        self._uu, _ = _derivative_coefficients(du, tu1, axis=1)         # (nv, nu - 2, 3)
        self._uv, _ = _derivative_coefficients(du, tv, axis=0)          # (nv - 1, nu - 1, 3)
        self._vv, _ = _derivative_coefficients(dv, tv[1:-1], axis=0)    # (nv - 2, nu, 3)

    def evaluate(self, uv):
        """Points in W at parameters (n, 2) = (u, v)."""
        ev = eval_many(*self._net, np.ascontiguousarray(uv[:, 0]), np.ascontiguousarray(uv[:, 1]))
        return ev[:, 0] @ self.rotation.T

    def hessian_bound(self, params, normals):
        """Bounds of ``|n . S_uu|, |n . S_uv|, |n . S_vv|`` over each triangle's preimage.

        On a knot cell, each second derivative is a convex combination (the B-spline
        basis is non-negative and sums to one) of a block of its derivative control
        points, so its component along n is at most the largest of theirs; a preimage
        overlapping several cells takes the union of their blocks.
        """
        nv, nu = self._n
        tu, tv = self._knots
        n_local = normals @ self.rotation              # the nets are in the face's frame
        su0, su1 = _span(tu, nu, params[..., 0].min(1)), _span(tu, nu, params[..., 0].max(1))
        sv0, sv1 = _span(tv, nv, params[..., 1].min(1)), _span(tv, nv, params[..., 1].max(1))
        extra_u, extra_v = int((su1 - su0).max()), int((sv1 - sv0).max())

        def block_max(net, rows0, nrows, cols0, ncols, last_row, last_col):
            # rows rows0 .. rows0 + nrows - 1 (clipped to the triangle's last span), likewise columns
            r = np.minimum(rows0[:, None] + np.arange(nrows), last_row[:, None])
            c = np.minimum(cols0[:, None] + np.arange(ncols), last_col[:, None])
            blk = net[r[:, :, None], c[:, None, :]]                    # (T, nrows, ncols, 3)
            return np.abs(np.einsum("trcd,td->trc", blk, n_local)).max(axis=(1, 2))

        # span (sv, su) uses uu rows sv-3..sv, columns su-3..su-2; uv rows sv-3..sv-1, columns su-3..su-1;
        # vv rows sv-3..sv-2, columns su-3..su
        A = block_max(self._uu, sv0 - 3, 4 + extra_v, su0 - 3, 2 + extra_u, sv1, su1 - 2)
        B = block_max(self._uv, sv0 - 3, 3 + extra_v, su0 - 3, 3 + extra_u, sv1 - 1, su1 - 1)
        C = block_max(self._vv, sv0 - 3, 2 + extra_v, su0 - 3, 4 + extra_u, sv1 - 2, su1)
        return A, B, C


class RevolutionPatch:
    """A surface of revolution ``(x, r(x) cos theta, r(x) sin theta)`` as the true surface of a mesh.

    Parameters
    ----------
    profile : RevolutionProfile
        r(x), a monotone piecewise cubic (PCHIP).
    """

    def __init__(self, profile):
        self.profile = profile
        pp = profile._interp                          # PPoly: breakpoints x, coefficients c[0] x^3 .. c[3]
        self._x, self._c = np.asarray(pp.x), np.asarray(pp.c)

    def evaluate(self, xt):
        """Points in W at parameters (n, 2) = (x [mm], theta [rad])."""
        x, th = xt[:, 0], xt[:, 1]
        r = self.profile.radius_at(x)
        return np.column_stack([x, r * np.cos(th), r * np.sin(th)])

    def hessian_bound(self, params, normals):
        """Bounds of ``|n . H_xx| <= |r''|, |n . H_xtheta| <= |r'|, |n . H_thetatheta| <= r`` over each preimage.

        r'' is linear on each cubic piece, so its largest magnitude over an x range
        inside one piece is at the range's ends; a range across pieces takes the
        largest over all of them. r' and r are bounded from the range's start by the
        mean value theorem.
        """
        xa, xb = params[..., 0].min(1), params[..., 0].max(1)
        xs, c = self._x, self._c
        last = len(xs) - 2
        ka = np.clip(np.searchsorted(xs, xa, side="right") - 1, 0, last)
        kb = np.clip(np.searchsorted(xs, xb, side="left") - 1, 0, last)

        def r2(k, x):
            return 6.0 * c[0, k] * (x - xs[k]) + 2.0 * c[1, k]

        ends = np.concatenate([np.abs(r2(np.arange(last + 1), xs[:-1])), np.abs(r2(np.arange(last + 1), xs[1:]))])
        A = np.where(ka == kb, np.maximum(np.abs(r2(ka, xa)), np.abs(r2(ka, xb))), ends.max())
        h = xb - xa
        slope = np.abs(self.profile.slope_at(xa)) + A * h
        B = slope
        C = self.profile.radius_at(xa) + slope * h
        return A, B, C


# -- one mesh against its surface -------------------------------------------------------------

def surface_deviation(mesh, params, patch, float32=True, subdivisions=SUBDIVISIONS):
    """Signed deviation of one surface mesh from its true surface, as upper bounds.

    Derivation. The mesh vertices are true-surface points at known parameters,
    so each triangle T has a preimage t, the triangle its vertices' parameters
    span. Over t, ``g(p) = (S(p) - v0) . n_T`` is the signed distance of the
    surface from T's plane (positive: the surface lies on the channel side of
    the mesh, i.e. the mesh lies in the material). g is sampled at the
    ``(n + 1)(n + 2) / 2`` points of t's lattice of n = ``subdivisions`` steps
    per edge. On each lattice cell c (t shrunk by 1/n, parameter extents du,
    dv) g differs from the linear interpolant of its corner samples by at most
    ``(A du^2 + 2 B du dv + C dv^2) / 8``: with barycentric weights l_i,
    ``sum_i l_i g(p_i) - g(p) = 1/2 sum_i l_i (p_i - p)^T H(xi_i) (p_i - p)``
    (Taylor with Lagrange remainder, ``sum_i l_i (p_i - p) = 0``), the weighted
    variance of u over the corners is at most du^2 / 4 (Popoviciu), of v at
    most dv^2 / 4, and the cross term at most du dv / 4 (Cauchy-Schwarz); A, B,
    C bound ``|n_T . S_uu|, |n_T . S_uv|, |n_T . S_vv|`` over t (the patch's
    ``hessian_bound``). The interpolant's extremes are at the corners, so
    ``max g <= max sample + remainder`` and ``min g >= min sample -
    remainder`` over t: the bound is the sampled extreme plus the remainder,
    the largest over all triangles.

    What this bounds: distances along the triangle's normal between its plane
    and the surface points of its preimage. A surface that deviates little is
    a graph over each small triangle, and the length along the normal between
    a point and the other sheet is at least the distance to the nearest point
    of the other, so these are bounds on the distance of the mesh from the
    surface and of the surface from the mesh, on the side of the normal's
    sign. One assumption: the surface point over a mesh point near a triangle
    edge may have its parameters just inside the neighbour's preimage (the
    parametrisation is not affine in the triangle), a shift of the order of
    the interpolation error itself, whose effect on the distance is smaller
    again by the ratio of that error to the triangle's size; the independent
    check of ``test/test_mesh_deviation.py`` (exact closest points, both
    ways) finds the bound holding. Near a mesh boundary the surface runs on
    past the mesh edge (the patches are cut beyond the channel), which no
    figure here describes.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Normals into the channel; vertex i at ``params.reshape(-1, 2)[i]``.
    params : (S, C, 2) float
        From :meth:`Blisk.channel_mesh_parameters`.
    patch : SplineFacePatch or RevolutionPatch
        The true surface in the mesh's frame.
    float32 : bool
        Measure the mesh as a binary STL stores it (vertices rounded to float32).
    subdivisions : int

    Returns
    -------
    SurfaceDeviation

    Raises
    ------
    EdmError
        INTERNAL when a vertex is not the surface at its parameters (the
        meshing and ``params`` disagree).
    """
    uv = np.asarray(params, dtype=np.float64).reshape(-1, 2)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if len(uv) != len(vertices):
        raise EdmError(ErrorCode.INTERNAL, f"mesh deviation: {len(vertices)} vertices but {len(uv)} parameters")
    off = np.linalg.norm(patch.evaluate(uv) - vertices, axis=1).max()
    if off > VERTEX_TOLERANCE:
        raise EdmError(ErrorCode.INTERNAL, f"mesh deviation: a mesh vertex lies {off:.3g} mm from the surface at its "
                                           "parameters (meshing and parameters disagree)")
    if float32:
        vertices = vertices.astype(np.float32).astype(np.float64)
    faces = np.asarray(mesh.faces)
    corners = vertices[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1)
    if not (length > 0).all():
        raise EdmError(ErrorCode.INTERNAL, "mesh deviation: the mesh has a degenerate triangle")
    normals /= length[:, None]
    tri_params = uv[faces]
    low, high, rem, arg_low, arg_high = plane_deviation(tri_params, corners, normals, patch.evaluate,
                                                        patch.hessian_bound, subdivisions)
    into_channel, into_material = rem - low, high + rem
    lam = lattice(subdivisions)
    i, j = int(np.argmax(into_channel)), int(np.argmax(into_material))
    at_c = patch.evaluate((lam[arg_low[i]] @ tri_params[i])[None])[0]
    at_m = patch.evaluate((lam[arg_high[j]] @ tri_params[j])[None])[0]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max()
    return SurfaceDeviation(
        into_channel=float(max(into_channel.max(), 0.0)), into_material=float(max(into_material.max(), 0.0)),
        measured_into_channel=float(max(-low.min(), 0.0)), measured_into_material=float(max(high.max(), 0.0)),
        remainder=float(rem.max()), at_into_channel=tuple(map(float, at_c)), at_into_material=tuple(map(float, at_m)),
        subdivisions=int(subdivisions), sample_spacing=float(edges / subdivisions), triangles=len(faces))


def channel_patches(blisk, channel=0):
    """The true surfaces of channel k's four meshes, in W: ``label -> patch``."""
    turn = lambda k: rotation_about_x(k * blisk.pitch)[:3, :3]      # noqa: E731
    out = {"suction": SplineFacePatch(blisk.suction_face.surface, turn(channel)),
           "pressure": SplineFacePatch(blisk.pressure_face.surface, turn(channel + 1))}
    for label, profile in (("hub", blisk.hub), ("shroud", blisk.shroud)):
        out[label] = RevolutionPatch(profile)
    return out


def channel_mesh_deviation(blisk, channel=0, resolution=0.5, meshes=None, float32=True, subdivisions=SUBDIVISIONS):
    """Deviation of channel k's surface meshes from the true surfaces, per surface and side.

    Parameters
    ----------
    blisk : Blisk
    channel : int
    resolution : float
        Of :meth:`Blisk.channel_meshes` [mm].
    meshes : dict, optional
        Those meshes, if already built.
    float32 : bool
        Measure the meshes as a binary STL stores them.
    subdivisions : int

    Returns
    -------
    dict
        ``label -> SurfaceDeviation`` (see :func:`surface_deviation`).
    """
    if meshes is None:
        meshes = blisk.channel_meshes(channel, resolution)
    params = blisk.channel_mesh_parameters(resolution)
    patches = channel_patches(blisk, channel)
    out = {}
    for label, mesh in meshes.items():
        p = params[label]
        if label in ("hub", "shroud"):                # the walls' parameters are channel 0's angles
            p = p + np.array([0.0, channel * blisk.pitch])
        out[label] = surface_deviation(mesh, p, patches[label], float32, subdivisions)
    return out


#: the deviation cache's file format: a new one measures every channel again
CACHE_FORMAT = "edm_planner.mesh_deviation/2"
#: deviation files kept (the least recently used go first); each is about 2 kB
CACHE_KEEP = 256


def cached_channel_mesh_deviation(blisk, channel=0, resolution=0.5, float32=True, subdivisions=SUBDIVISIONS, *,
                                  cache_dir, meshes=None):
    """:func:`channel_mesh_deviation`, from ``<cache_dir>/mesh_deviation/`` when it holds it (None: no cache).

    Every plan export states its workpiece's deviation, about 0.5 s on a 2-core cell PC, and a cell exports
    every channel of a blisk, each from a new process. The file is keyed (:mod:`.disk_cache`) by the blisk as
    the nodes exchange it (``Blisk.to_dict``), the channel, the resolution, ``float32``, ``subdivisions`` and
    the package's sources, and read back bit for bit. ``meshes``, if given, must be
    ``blisk.channel_meshes(channel, resolution)``: the key names the blisk, not the meshes.
    """
    if not cache_dir:
        return channel_mesh_deviation(blisk, channel, resolution, meshes, float32, subdivisions)
    key = content_key({"format": CACHE_FORMAT, "blisk": blisk.to_dict(), "channel": int(channel),
                       "resolution": float(resolution), "float32": bool(float32), "subdivisions": int(subdivisions)})
    return get_or_make_json(pathlib.Path(cache_dir) / "mesh_deviation" / f"{key[:32]}.json",
                            lambda: channel_mesh_deviation(blisk, channel, resolution, meshes, float32, subdivisions),
                            fmt=CACHE_FORMAT, keep=CACHE_KEEP, what="mesh deviation",
                            encode=lambda deviation: {label: d.to_dict() for label, d in deviation.items()},
                            decode=_deviation_of)


def _deviation_of(surfaces):
    """The deviation of a cached file's value (per surface label, :meth:`SurfaceDeviation.to_dict`)."""
    return {label: SurfaceDeviation(**dict(d, at_into_channel=tuple(d["at_into_channel"]),
                                           at_into_material=tuple(d["at_into_material"])))
            for label, d in surfaces.items()}
