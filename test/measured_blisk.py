"""A blisk as measured for the tests: every blade's faces off nominal by up to +-0.05 mm at random.

Each face of each blade moves along its own normal by a random amount (uniform in +-``amplitude``, one
per face, seeded), tapered to nothing over the first and last tenth of the chord (the faces meet at the
edges). The blades are written as section CSV files in their own place on the part (blade k turned by k
pitches), with a YAML that gives the nominal blisk and, under ``as_measured``, every blade; the offsets are
returned so a test knows which channel narrows most.
"""

import pathlib

import numpy as np
from scipy.ndimage import gaussian_filter

CONFIG = pathlib.Path(__file__).resolve().parents[1] / "config"


def _arc_per_normal(face, sections):
    """Angle [rad] per mm of normal offset of a blade face at the sections' stations: the face is
    theta = f(x, r), so a move ``d`` along its normal turns it by ``d * sqrt(1 + (r f_x)^2 + (r f_r)^2) / r``
    (from the face spline's own gradient, so smooth; capped at 3 / r where the face turns round an edge).
    Sections outside the face (the blade's extension into hub and shroud) take their neighbour's."""
    _, inside, grad = face.theta_at(sections.x.ravel(), sections.r.ravel(), with_gradient=True)
    r = sections.r.ravel()
    factor = np.minimum(np.sqrt(1.0 + (r * grad[:, 0]) ** 2 + (r * grad[:, 1]) ** 2), 3.0).reshape(sections.shape)
    rows = np.nonzero(inside.reshape(sections.shape)[:, sections.shape[1] // 2])[0]     # by mid chord
    nearest = rows[np.abs(np.arange(sections.shape[0])[:, None] - rows[None, :]).argmin(axis=1)]
    # smoothed over a few stations: measured faces are smooth, and so must the offset be (a wiggle of
    # a few micrometres between stations gives the face spline bumps the fast field's bound picks up)
    return gaussian_filter(factor[nearest], sigma=4.0, mode="nearest") / sections.r


def write_measured_blisk(directory, blisk, amplitude=0.05, seed=7, tolerance=0.005, only_channel=None):
    """Write ``directory/blisk.yaml`` and one CSV per measured blade.

    Parameters
    ----------
    blisk : Blisk
        The nominal blisk (the default blisk's YAML is reused for its nominal keys).
    only_channel : int, optional
        Give only the two blades of this channel as measured, each off nominal on the face towards the
        channel alone (the same walls as with every blade measured, the other channels all nominal).

    Returns
    -------
    path : pathlib.Path
        The YAML.
    offsets : (N, 2) float
        Per blade, the normal offset of its pressure (minus) and suction (plus) face [mm], positive towards
        +theta; 0 for blades not measured.
    """
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    n = blisk.blade_count
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(-amplitude, amplitude, (n, 2))
    chosen = range(n)
    if only_channel is not None:
        k = int(only_channel)
        chosen = [k, (k + 1) % n]
        keep = offsets.copy()
        offsets[:] = 0.0
        offsets[k, 1], offsets[(k + 1) % n, 0] = keep[k, 1], keep[(k + 1) % n, 0]
    base = blisk.blade
    # tapered smoothly from 0 at the edges to 1 over the first and last tenth of the chord: a measured face
    # deviates smoothly, and the faces meet at the edges (a taper over the edges' rounding alone would
    # put a bump of 0.05 mm into a tenth of a millimetre of face)
    x0, x1 = base.x[:, :1], base.x[:, -1:]
    t = np.clip(np.minimum(base.x - x0, x1 - base.x) / (0.1 * (x1 - x0)), 0.0, 1.0)
    taper = t * t * (3 - 2 * t)
    arc_minus = _arc_per_normal(blisk.pressure_face, base)
    arc_plus = _arc_per_normal(blisk.suction_face, base)
    entries = []
    for k in chosen:
        tm = base.theta_minus + offsets[k, 0] * taper * arc_minus + k * blisk.pitch
        tp = base.theta_plus + offsets[k, 1] * taper * arc_plus + k * blisk.pitch
        rows = ["section,x,r,theta_1,theta_2"]
        for i in range(base.shape[0]):
            for j in range(base.shape[1]):
                rows.append(f"{i},{float(base.x[i, j])!r},{float(base.r[i, j])!r},{float(tm[i, j])!r},{float(tp[i, j])!r}")
        (directory / f"blade{k:02d}.csv").write_text("\n".join(rows) + "\n")
        entries.append(f"    - {{blade: {k}, sections: {{file: blade{k:02d}.csv, format: csv}}}}")
    text = (CONFIG / "default_blisk.yaml").read_text()
    text += f"\nas_measured:\n  tolerance: {tolerance}\n  blades:\n" + "\n".join(entries) + "\n"
    path = directory / "blisk.yaml"
    path.write_text(text)
    return path, offsets


def narrowing(offsets):
    """Per channel k: how far its walls come into it [mm] at most, blade k's suction face (+) or blade
    k+1's pressure face (-)."""
    return np.maximum(offsets[:, 1], -np.roll(offsets[:, 0], -1))


def whole_blisk_mesh(nominal, measured=None, resolution=1.0, sections=720):
    """The whole blisk as one closed mesh, as an inspection system's scan gives it: every blade (as measured
    where ``measured`` gives it, else nominal) joined with a hub ring and a shroud ring by a mesh boolean
    (manifold3d, in double precision).

    Parameters
    ----------
    nominal : Blisk
    measured : MeasuredBlades, optional
    resolution : float
        Edge length [mm] of the blade faces' grids (about).
    sections : int
        Facets of the rings round the turn.

    Returns
    -------
    trimesh.Trimesh
    """
    import manifold3d
    import trimesh

    from edm_planner.geometry.blisk import Blisk
    from edm_planner.geometry.mesh_build import closed_blade_mesh

    def solid(mesh):
        return manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(mesh.vertices, dtype=np.float64),
                                                     np.ascontiguousarray(mesh.faces, dtype=np.uint64)))

    hub, shroud = nominal.hub, nominal.shroud
    x0 = max(hub.x_range[0], shroud.x_range[0])
    x1 = min(hub.x_range[1], shroud.x_range[1])
    xs = np.linspace(x0, x1, 81)
    r_in = float(hub.radius_at(xs).min()) - 10.0
    r_out = float(shroud.radius_at(xs).max()) + 10.0
    parts = []
    for inner, outer in ((np.full_like(xs, r_in), hub.radius_at(xs)), (shroud.radius_at(xs), np.full_like(xs, r_out))):
        # (radius, height) round the ring's cross-section, counter-clockwise: outward faces
        ring = np.r_[np.c_[inner, xs], np.c_[outer[::-1], xs[::-1]], [[inner[0], xs[0]]]]
        mesh = trimesh.creation.revolve(ring, sections=sections)
        if mesh.volume < 0:
            mesh.invert()
        v = mesh.vertices
        mesh = trimesh.Trimesh(np.c_[v[:, 2], v[:, 0], v[:, 1]], mesh.faces, process=True)   # Z onto X
        parts.append(solid(mesh))
    n = nominal.blade_count
    given = {} if measured is None else measured.blades
    for k in range(n):
        blade = Blisk(n, hub, shroud, given.get(k, nominal.blade))
        minus, plus = blade._face_grids(resolution)
        mesh = closed_blade_mesh(minus, plus)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(k * nominal.pitch, [1, 0, 0]))
        parts.append(solid(mesh))
    # slivers where the blades meet the rings collapsed (a scan has none; the loader drops zero-area triangles)
    whole = manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add).simplify(1e-6).to_mesh64()
    return trimesh.Trimesh(np.asarray(whole.vert_properties)[:, :3], np.asarray(whole.tri_verts), process=True)
