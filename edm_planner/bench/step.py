"""Bench suite ``step`` (issue 28, part 1): a whole 60-blade blisk through STEP, end to end.

The default blisk (``config/default_blisk.yaml``, 60 blades) is written as one STEP solid with OpenCascade
(:mod:`.step_writer`: blade 0 lofted through every :data:`SECTION_STRIDE`-th of its sections and every
:data:`STATION_STRIDE`-nd station, 59 copies turned round X, hub and shroud rings, one boolean fuse), read back
with :func:`~edm_planner.geometry.loader.load_geometry` (the STEP import with its default section and station
counts) and compared with the parametric blisk: the blade count found, the round trip
(:func:`.step_writer.wall_deviation`: channel 0's walls, imported against parametric, largest distance along
the circle) and the import's own fit (``step_fit_deviation_mm``).

Fusing 60 blades takes minutes, so the file is kept in ``~/.cache/edm_planner/step_bench/`` under the SHA-256
of what it is written from (:func:`writer_key`: the writer's functions, the blade sections, the hub and
shroud profiles, the blade count, the strides, the OCP version): a later run reads it, and reports the write
time measured when it was written (``write_cached``: true). The import is timed every run. Too slow for the
test suite; the sector and three-blade files of ``test/test_step_import.py`` test the same import.
"""

import hashlib
import inspect
import json
import logging
import os
import pathlib
import time

import numpy as np

from ..environment import CACHE_ROOT
from ..geometry.loader import load_geometry
from . import step_writer as sw
from .common import CONFIG
from .cpu import cpu_label, cpu_record

_log = logging.getLogger(__name__)

#: the written blade: every third section, every second station (the three-blade test file's loft)
SECTION_STRIDE = 3
STATION_STRIDE = 2
#: where the written files are kept
CACHE_DIR = pathlib.Path(CACHE_ROOT) / "step_bench"


#: the writer's functions the file is made by (their source is part of the cache key)
WRITER = (sw.bspline, sw.cart, sw.loft_rows, sw.blade_solid,
          sw.ring, sw.rotated, sw.transformed, sw.fuse, sw.whole_solid,
          sw.write_step)


def writer_key(blisk, section_stride=SECTION_STRIDE, station_stride=STATION_STRIDE):
    """SHA-256 of everything the written file depends on: the writer's functions (their source), the blade
    sections, the hub and shroud profiles, the blade count, the strides, the rings' radii and extent, the OCP
    version."""
    import OCP

    h = hashlib.sha256()
    for fn in WRITER:
        h.update(inspect.getsource(fn).encode())
    b = blisk.blade
    for a in (b.x, b.r, b.theta_minus, b.theta_plus, blisk.hub.points, blisk.shroud.points):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(json.dumps([int(blisk.blade_count), section_stride, station_stride, sw.R_BORE, sw.R_OUTER,
                         list(sw.X_RANGE), getattr(OCP, "__version__", "")]).encode())
    return h.hexdigest()


def whole_blisk_step(blisk, cache_dir=CACHE_DIR):
    """(path, write record) of the whole blisk's STEP file, written unless the cache holds it."""
    key = writer_key(blisk)
    cache_dir = pathlib.Path(cache_dir)
    path = cache_dir / f"{key[:32]}.whole{blisk.blade_count}.step"
    meta = path.with_suffix(".json")
    if path.exists() and meta.exists():
        record = json.loads(meta.read_text())
        record["write_cached"] = True
        return path, record
    cache_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    blade = sw.blade_solid(blisk, SECTION_STRIDE, STATION_STRIDE)
    t1, c1 = time.perf_counter(), time.process_time()
    solid = sw.whole_solid(blisk, blade, blisk.blade_count)
    t2, c2 = time.perf_counter(), time.process_time()
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID

    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.step")
    sw.write_step(solid, tmp)
    t3 = time.perf_counter()
    record = {"key": key, "loft_s": round(t1 - t0, 2), "fuse_s": round(t2 - t1, 2), "fuse_cpu_s": round(c2 - c1, 2),
              "step_write_s": round(t3 - t2, 2), "write_s": round(t3 - t0, 2),
              "solids": sw.count(solid, TopAbs_SOLID), "faces": sw.count(solid, TopAbs_FACE),
              "valid": sw.is_valid(solid), "file_mb": round(tmp.stat().st_size / 2 ** 20, 2),
              "written_on": cpu_label(cpu_record()),
              "written_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    os.replace(tmp, path)
    meta.write_text(json.dumps(record, indent=2))
    record["write_cached"] = False
    return path, record


def bench_step(cache_dir=CACHE_DIR):
    cpu = cpu_record()
    nominal = load_geometry(CONFIG / "default_blisk.yaml").blisk
    out = {"cpu": cpu_label(cpu), "blisk": "config/default_blisk.yaml", "blade_count": int(nominal.blade_count),
           "section_stride": SECTION_STRIDE, "station_stride": STATION_STRIDE}
    path, write = whole_blisk_step(nominal, cache_dir)
    out["file"] = str(path)
    out["write"] = write
    t, c = time.perf_counter(), time.process_time()
    g = load_geometry(path)
    out["import_s"] = round(time.perf_counter() - t, 2)
    out["import_cpu_s"] = round(time.process_time() - c, 2)        # this process's CPU time: on a busy machine
    info = g.step_import
    out["found"] = {k: info.get(k) for k in ("kind", "blade_count", "mid_span_blades", "transform_applied",
                                             "section_count", "station_count", "root_fillet_depth",
                                             "tip_fillet_depth", "fillet_faces", "section_radii")}
    out["blade_count_found"] = int(g.blisk.blade_count)
    out["blade_count_ok"] = g.blisk.blade_count == nominal.blade_count
    dev, n, n0 = sw.wall_deviation(nominal, g.blisk)
    out["round_trip_mm"] = round(dev, 4)
    out["round_trip_points"] = [n, n0]
    out["fit_deviation_mm"] = None if info.get("fit_deviation_mm") is None else round(info["fit_deviation_mm"], 4)
    out["fit_points"] = info.get("fit_points")
    _log.warning("step: %s", out)
    return out
