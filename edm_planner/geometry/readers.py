"""Readers for measured blade sections and meridional lines.

Formats:

* ``nasa_table``: the NASA Rotor 37 "Table IV" layout -- blocks headed
  ``SURFACE NUMBER k`` with rows ``J Z R THETA1 THETA2`` (Z the rotor axis).
  This is what in-situ measurement of a blisk yields: per spanwise section,
  points with axial position, radius and the angle of each blade side.
* ``csv``: a header line and rows ``section, x, r, theta_1, theta_2``
  (section an integer, hub first; rows of a section in chord order).
* ``nasa_meridional``: the Rotor 37 "Table V" layout -- named blocks
  (``Zhub``, ``Rhub``, ``Zshroud``, ``Rshroud``) of whitespace-separated numbers.

Lengths are scaled to millimetres by ``length_unit``; angles are radians.
"""

import re

import numpy as np

from ..errors import GeometryError, GeometryFileError
from .file_size import check_file_size
from .sections import BladeSections

LENGTH_UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


def unit_scale(unit, where):
    """Millimetres per ``unit``."""
    if unit not in LENGTH_UNITS:
        raise GeometryError(f"{where}.length_unit: must be one of {sorted(LENGTH_UNITS)}, got {unit!r}")
    return LENGTH_UNITS[unit]


def _read_text(path, max_bytes=None):
    """The file's text; GeometryFileError when it is larger than ``max_bytes`` (checked before reading)."""
    if max_bytes is not None:
        check_file_size(path, max_bytes, str(path), "table")
    try:
        return path.read_text(encoding="utf-8", errors="strict")
    except FileNotFoundError:
        raise GeometryFileError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GeometryFileError(f"{path}: cannot read as text ({exc})") from None


def _sections_from_rows(rows, path):
    """rows: list (per section) of (C, 4) arrays [x, r, th1, th2] in mm/rad."""
    counts = {len(r) for r in rows}
    if len(rows) < 2:
        raise GeometryError(f"{path}: needs at least 2 blade sections, found {len(rows)}")
    if len(counts) != 1:
        raise GeometryError(
            f"{path}: every section must have the same number of points, found {sorted(counts)}")
    a = np.stack(rows)
    if not np.all(np.isfinite(a)):
        raise GeometryError(f"{path}: contains NaN or infinite values")
    th_minus = np.minimum(a[..., 2], a[..., 3])
    th_plus = np.maximum(a[..., 2], a[..., 3])
    return BladeSections(a[..., 0], a[..., 1], th_minus, th_plus)


def read_nasa_table(path, length_unit="cm", max_bytes=None):
    """Blade sections from a NASA 'Table IV' file (e.g. Rotor 37); ``max_bytes``: size limit (None: none).

    Returns
    -------
    BladeSections
    """
    scale = unit_scale(length_unit, "blade.sections")
    text = _read_text(path, max_bytes)
    blocks = re.split(r"SURFACE NUMBER\s+\d+", text)[1:]
    if not blocks:
        raise GeometryError(f"{path}: no 'SURFACE NUMBER' blocks found; not a NASA blade table")
    rows = []
    for k, block in enumerate(blocks, start=1):
        pts = []
        for line in block.splitlines():
            fields = line.split()
            if len(fields) == 5 and re.fullmatch(r"\d+", fields[0]):
                try:
                    pts.append([float(v) for v in fields[1:]])
                except ValueError:
                    raise GeometryError(f"{path}: surface {k}: unreadable row {line.strip()!r}") from None
        if not pts:
            raise GeometryError(f"{path}: surface {k} has no data rows (J Z R THETA1 THETA2)")
        p = np.asarray(pts)
        rows.append(np.column_stack([p[:, 0] * scale, p[:, 1] * scale, p[:, 2], p[:, 3]]))
    return _sections_from_rows(rows, path)


def read_sections_csv(path, length_unit="mm", max_bytes=None):
    """Blade sections from a CSV ``section, x, r, theta_1, theta_2``; ``max_bytes``: size limit (None: none)."""
    scale = unit_scale(length_unit, "blade.sections")
    text = _read_text(path, max_bytes)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) < 2:
        raise GeometryError(f"{path}: empty section table")
    by_section = {}
    for n, line in enumerate(lines[1:], start=2):
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != 5:
            raise GeometryError(f"{path}: line {n}: expected 5 columns section,x,r,theta_1,theta_2")
        try:
            sec = int(fields[0])
            vals = [float(v) for v in fields[1:]]
        except ValueError:
            raise GeometryError(f"{path}: line {n}: not numbers: {line.strip()!r}") from None
        by_section.setdefault(sec, []).append([vals[0] * scale, vals[1] * scale, vals[2], vals[3]])
    rows = [np.asarray(by_section[k]) for k in sorted(by_section)]
    return _sections_from_rows(rows, path)


def read_nasa_meridional(path, curve, length_unit="cm", max_bytes=None):
    """A hub or shroud line from a NASA 'Table V' file.

    Parameters
    ----------
    curve : {'hub', 'shroud'}
    max_bytes : int, optional
        Size limit of the file, checked before it is read (None: none).

    Returns
    -------
    points : (n, 2) float
        [x, r] in mm.
    """
    if curve not in ("hub", "shroud"):
        raise GeometryError(f"meridional file {path}: curve must be 'hub' or 'shroud', got {curve!r}")
    scale = unit_scale(length_unit, f"{curve}_profile")
    text = _read_text(path, max_bytes)
    values = {}
    for name in (f"Z{curve}", f"R{curve}"):
        m = re.search(rf"^\s*{name}\s*\n\s*(\d+)\s+points\s*\n(.*?)(?:\n\s*\n|\Z)", text, re.S | re.M)
        if not m:
            raise GeometryError(f"{path}: no '{name}' block found; not a NASA meridional table")
        nums = np.array(m.group(2).split(), dtype=np.float64)
        if len(nums) != int(m.group(1)):
            raise GeometryError(f"{path}: block {name} announces {m.group(1)} points but has {len(nums)}")
        values[name] = nums * scale
    return np.column_stack([values[f"Z{curve}"], values[f"R{curve}"]])
