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
