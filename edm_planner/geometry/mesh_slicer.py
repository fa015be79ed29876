"""Exact cross-sections of a closed triangle mesh by many planes ``x = x0`` at once.

:class:`MeshSlicer` cuts every face of a mesh with a whole array of planes
normal to the blisk axis in one vectorised pass and answers, per plane, the
questions :func:`~.mesh_sections.mesh_to_sections` asks: the radial extent of
the cross-section, its end caps, the radial range where circles meet it
exactly twice, and where the circle ``{(x0, r0 cos t, r0 sin t)}`` crosses it.

Units: millimetres and radians. Frame W: X is the blisk axis,
``theta = atan2(z, y)``.
"""

import numpy as np


class MeshSlicer:
    """Cross-sections of a closed mesh by many planes ``x = x0`` at once.

    The mesh is rotated by ``-theta0`` about X so that the blade lies around
    angle 0 and ``atan2`` needs no unwrapping.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        A closed triangle mesh in W [mm].
    theta0 : float
        Angle about X the mesh is turned back by [rad] (the blade's mean angle).

    Attributes
    ----------
    tri : (F, 3, 3) float
        The triangles in the rotated frame [mm].
    xmin, xmax : (F,) float
        Axial extent of each triangle [mm].
    normal : (F, 3) float
        Unit face normals in the rotated frame (zero for degenerate triangles).
    """

    def __init__(self, mesh, theta0):
        v = np.asarray(mesh.vertices, dtype=np.float64)
        c, s = np.cos(theta0), np.sin(theta0)
        rot = np.column_stack([v[:, 0], c * v[:, 1] + s * v[:, 2], -s * v[:, 1] + c * v[:, 2]])
        tri = rot[np.asarray(mesh.faces)]  # (F, 3, 3)
        self.tri = np.ascontiguousarray(tri)
        self.xmin = tri[:, :, 0].min(axis=1)
        self.xmax = tri[:, :, 0].max(axis=1)
        # unit face normals in the rotated frame (zero for degenerate triangles)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1)
        self.normal = n / np.where(length > 0, length, 1.0)[:, None]

    def slice(self, x0):
        """Segments of the cross-sections at the planes ``x = x0``.

        Parameters
        ----------
        x0 : (P,) float

        Returns
        -------
        plane : (N,) int
            Plane index of each segment.
        a, b : (N, 2) float
            End points of each segment in the rotated (y, z) plane [mm].
        face : (N,) int
            The mesh face each segment cuts.
        """
        x0 = np.asarray(x0, dtype=np.float64)
        order = np.argsort(x0, kind="stable")
        xs = x0[order]
        # a face crosses the plane when some vertex is below (d < 0) and some
        # is on or above (d >= 0): x0 in (xmin, xmax]
        lo = np.searchsorted(xs, self.xmin, side="right")
        hi = np.searchsorted(xs, self.xmax, side="right")
        count = hi - lo
        total = int(count.sum())
        face = np.repeat(np.arange(len(count)), count)
        start = np.cumsum(count) - count
        plane = order[lo[face] + np.arange(total) - start[face]]
        tri = self.tri[face]  # (N, 3, 3)
        d = tri[:, :, 0] - x0[plane, None]  # (N, 3)
        above = d >= 0
        # the lone vertex on its side of the plane, and the other two
        lone = np.where(above.sum(axis=1) == 1, np.argmax(above, axis=1), np.argmin(above, axis=1))
        k1, k2 = (lone + 1) % 3, (lone + 2) % 3
        rows = np.arange(len(face))
        d0, d1, d2 = d[rows, lone], d[rows, k1], d[rows, k2]
        p0, p1, p2 = tri[rows, lone, 1:], tri[rows, k1, 1:], tri[rows, k2, 1:]
        a = p0 + (d0 / (d0 - d1))[:, None] * (p1 - p0)
        b = p0 + (d0 / (d0 - d2))[:, None] * (p2 - p0)
        return plane, a, b, face

    def radial_range(self, x0):
        """Exact radial extent of the cross-sections.

        Returns
        -------
        r_lo, r_hi : (P,) float
            Smallest distance from the axis to the section and largest one
            (``inf``/``-inf`` where the plane misses the mesh) [mm].
        dip : (P,) float
            Largest amount by which a segment comes closer to the axis than
            both its end points (chords across a cap) [mm].
        """
        x0 = np.asarray(x0, dtype=np.float64)
        plane, closest, near, far = self._radial_intervals(x0)
        r_lo = np.full(len(x0), np.inf)
        r_hi = np.full(len(x0), -np.inf)
        dip = np.zeros(len(x0))
        np.minimum.at(r_lo, plane, closest)
        np.maximum.at(r_hi, plane, far)
        np.maximum.at(dip, plane, near - closest)
        return r_lo, r_hi, dip

    def _radial_intervals(self, x0, with_normal=False):
        """Per segment of the cross-sections: plane, closest, nearer-end and farther-end radius [mm].

        With ``with_normal`` also the radial component of the unit normal of
        the face each segment cuts (at the segment's middle).
        """
        plane, a, b, face = self.slice(x0)
        ab = b - a
        length2 = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(-np.einsum("ij,ij->i", a, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        closest = np.linalg.norm(a + t[:, None] * ab, axis=1)
        ra, rb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        out = (plane, closest, np.minimum(ra, rb), np.maximum(ra, rb))
        if with_normal:
            mid = 0.5 * (a + b)
            e_r = mid / np.maximum(np.linalg.norm(mid, axis=1), 1e-300)[:, None]
            out += (np.einsum("ij,ij->i", self.normal[face, 1:], e_r),)
        return out

    def end_caps(self, x0, cos_min):
        """Radial range of the end caps of each plane's cross-section.

        A cap segment cuts a face whose unit normal points along +r (tip
        end, in the outer half of the cross-section's radial extent) or -r
        (hub end, inner half) with a component of at least ``cos_min``.

        Returns
        -------
        hub_cap_hi : (P,) float
            Largest radius of the hub-end cap segments [mm] (-inf if none).
        tip_cap_lo : (P,) float
            Smallest radius (closest approach) of the tip-end cap segments [mm]
            (inf if none).
        """
        x0 = np.asarray(x0, dtype=np.float64)
        P = len(x0)
        plane, closest, _, far, n_r = self._radial_intervals(x0, with_normal=True)
        r_lo = np.full(P, np.inf)
        r_hi = np.full(P, -np.inf)
        np.minimum.at(r_lo, plane, closest)
        np.maximum.at(r_hi, plane, far)
        r_mid = 0.5 * (r_lo + r_hi)[plane]
        hub_cap_hi = np.full(P, -np.inf)
        tip_cap_lo = np.full(P, np.inf)
        hub = (n_r <= -cos_min) & (far <= r_mid)
        tip = (n_r >= cos_min) & (closest >= r_mid)
        np.maximum.at(hub_cap_hi, plane[hub], far[hub])
        np.minimum.at(tip_cap_lo, plane[tip], closest[tip])
        return hub_cap_hi, tip_cap_lo

    def single_interval_range(self, x0, tol):
        """Radial range about mid-span in which every circle meets the cross-section exactly twice.

        A circle of radius r crosses a segment once if r lies between the
        radii of its end points, and twice if r lies between the segment's
        closest approach to the axis and its nearer end point; summed over
        the segments this gives the exact number of crossings n(r) of every
        circle of the plane, piecewise constant in r.

        Parameters
        ----------
        x0 : (P,) float
        tol : float
            Intervals of r shorter than this [mm] do not interrupt the range
            (shared end points of segments).

        Returns
        -------
        r_in_lo, r_in_hi : (P,) float
            The range of r about the middle of the cross-section's radial
            extent with n(r) == 2 [mm]; beyond it, towards either end, some
            circles meet the cross-section more than twice (an end cap
            dipping into the blade) or not at all. NaN where n != 2 at the
            middle.
        """
        x0 = np.asarray(x0, dtype=np.float64)
        P = len(x0)
        r_in_lo = np.full(P, np.nan)
        r_in_hi = np.full(P, np.nan)
        plane, closest, near, far = self._radial_intervals(x0)
        if len(plane) == 0:
            return r_in_lo, r_in_hi
        # events (plane, r, change of n): +1 at the nearer end, -1 at the farther end
        # (one crossing in between), +2 at the closest approach, -2 at the nearer end
        ev_plane = np.concatenate([plane, plane, plane, plane])
        ev_r = np.concatenate([near, far, closest, near])
        ev_dn = np.concatenate([np.ones_like(near), -np.ones_like(far),
                                np.full_like(near, 2.0), np.full_like(near, -2.0)])
        o = np.lexsort((ev_r, ev_plane))
        ev_plane, ev_r = ev_plane[o], ev_r[o]
        n = np.rint(np.cumsum(ev_dn[o]))       # n(r) just above each event; 0 after a plane's last one
        # interval k = (r_k, r_k+1) of a plane; runs of consecutive good intervals
        lo, hi = ev_r[:-1], ev_r[1:]
        same = ev_plane[1:] == ev_plane[:-1]
        good = same & ((n[:-1] == 2) | (hi - lo <= tol))
        run = np.cumsum(~good)
        r_mid = np.full(P, np.nan)
        first = np.ones(len(ev_r), dtype=bool)
        first[1:] = ~same
        last = np.ones(len(ev_r), dtype=bool)
        last[:-1] = ~same
        r_mid[ev_plane[first]] = 0.5 * (ev_r[first] + ev_r[last])
        k_mid = np.nonzero(same & (lo <= r_mid[ev_plane[:-1]]) & (r_mid[ev_plane[:-1]] < hi))[0]
        k_mid = k_mid[good[k_mid]]
        if len(k_mid) == 0:
            return r_in_lo, r_in_hi
        run_lo = np.full(run[-1] + 1, np.inf)
        run_hi = np.full(run[-1] + 1, -np.inf)
        np.minimum.at(run_lo, run[good], lo[good])
        np.maximum.at(run_hi, run[good], hi[good])
        pl = ev_plane[k_mid]
        r_in_lo[pl] = run_lo[run[k_mid]]
        r_in_hi[pl] = run_hi[run[k_mid]]
        return r_in_lo, r_in_hi

    def hits(self, x0, r0):
        """Does the circle (x0, r0) meet the mesh? (P,) bool."""
        r_lo, r_hi, _ = self.radial_range(x0)
        return (r_lo <= r0) & (r0 <= r_hi)

    def circle_angles(self, x0, r0, merge_tol):
        """Angles where the circles (x0, r0) cross the cross-sections.

        Parameters
        ----------
        x0, r0 : (P,) float
        merge_tol : float
            Crossings closer than this [mm] are one crossing (shared segment
            end points, tangency).

        Returns
        -------
        count : (P,) int
            Number of distinct crossings.
        t_min, t_max : (P,) float
            Smallest and largest crossing angle (rotated frame) [rad], NaN
            where there is no crossing.
        n_min, n_max : (P,) float
            Component along +theta of the unit normal of the face crossed at
            ``t_min`` and ``t_max`` (0 where there is no crossing). For an
            outward-wound solid the circle enters at its first crossing
            (``n_min < 0``) and leaves at its last (``n_max > 0``).
        """
        x0 = np.asarray(x0, dtype=np.float64)
        r0 = np.asarray(r0, dtype=np.float64)
        P = len(x0)
        plane, a, b, face = self.slice(x0)
        ab = b - a
        qa = np.einsum("ij,ij->i", ab, ab)
        qb = 2.0 * np.einsum("ij,ij->i", a, ab)
        qc = np.einsum("ij,ij->i", a, a) - r0[plane] ** 2
        disc = qb * qb - 4.0 * qa * qc
        ok = (disc >= 0) & (qa > 0)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        q = -0.5 * (qb + np.copysign(sq, qb))
        safe_q = np.where(q != 0, q, 1.0)
        t1 = np.where(ok, q / np.where(qa > 0, qa, 1.0), np.nan)
        t2 = np.where(ok & (q != 0), qc / safe_q, t1)
        t = np.stack([t1, t2], axis=1)  # (N, 2)
        # a circle through a segment's end point is found on both segments that
        # share it (then merged), whatever the rounding of the end point's radius
        valid = ok[:, None] & (t >= -1e-9) & (t <= 1.0 + 1e-9)
        seg_idx, root = np.nonzero(valid)
        pts = a[seg_idx] + t[seg_idx, root, None] * ab[seg_idx]
        pl = plane[seg_idx]
        ang = np.arctan2(pts[:, 1], pts[:, 0])
        nrm = self.normal[face[seg_idx]]
        n_theta = np.cos(ang) * nrm[:, 2] - np.sin(ang) * nrm[:, 1]
        count = np.zeros(P, dtype=np.int64)
        t_min = np.full(P, np.nan)
        t_max = np.full(P, np.nan)
        n_min = np.zeros(P)
        n_max = np.zeros(P)
        if len(ang) == 0:
            return count, t_min, t_max, n_min, n_max
        o = np.lexsort((ang, pl))
        pl, ang, n_theta = pl[o], ang[o], n_theta[o]
        new = np.ones(len(ang), dtype=bool)
        new[1:] = (pl[1:] != pl[:-1]) | (np.diff(ang) * r0[pl[1:]] > merge_tol)
        np.add.at(count, pl[new], 1)
        first = np.ones(len(ang), dtype=bool)
        first[1:] = pl[1:] != pl[:-1]
        last = np.ones(len(ang), dtype=bool)
        last[:-1] = pl[1:] != pl[:-1]
        t_min[pl[first]] = ang[first]
        t_max[pl[last]] = ang[last]
        n_min[pl[first]] = n_theta[first]
        n_max[pl[last]] = n_theta[last]
        return count, t_min, t_max, n_min, n_max
