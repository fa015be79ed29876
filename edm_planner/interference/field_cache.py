"""The fast field's disk cache: one ``.npz`` per geometry and spacing, checked before use, written atomically.

The file holds the field's arrays (:data:`ARRAYS`) and a JSON record of its
figures (error bounds, build statistics) under the version of the layout
(``CACHE_VERSION``) and a fingerprint of everything the field was built
from. A file of another version or geometry, of the wrong shapes or layout,
or damaged (the CRC-32 check of :func:`.npz_map.map_npz`) is not used: the
field is rebuilt and the file rewritten.
"""

import hashlib
import json
import logging
import os
import pathlib
import re
import tempfile

import numpy as np

from . import SURFACES
from .field_params import CACHE_VERSION, FieldParams, GridShape
from .npz_map import map_npz

_log = logging.getLogger(__name__)

#: the field's arrays in the cache, by attribute name (stored without the leading underscore)
ARRAYS = ("_fp", "_ip", "_grid", "_hs", "_line_uv", "_coarse_uv", "_kind", "_line_theta", "_line_inside")


def cache_path(cache_dir, cache_key, spacing):
    """The cache file of a field: ``<cache_dir>/<key>.fast_field.s<spacing>.npz``; None without a directory or key.

    A key that is no plain file name is replaced by its SHA-256.
    """
    if cache_dir is None or not cache_key:
        return None
    key = str(cache_key)
    if not re.fullmatch(r"[A-Za-z0-9_.\-]{1,100}", key):
        key = hashlib.sha256(key.encode()).hexdigest()
    return pathlib.Path(cache_dir) / f"{key}.fast_field.s{spacing:g}.npz"


def fingerprint(arrays, pitch, options):
    """SHA-256 (hex) of the geometry's arrays, the pitch, ``CACHE_VERSION`` and the build options (a list)."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(np.float64(pitch).tobytes())
    h.update(json.dumps([CACHE_VERSION] + list(options)).encode())
    return h.hexdigest()


def write_cache(path, arrays, meta):
    """Write ``arrays`` (name -> array, names as in :data:`ARRAYS`) and ``meta`` (JSON) to ``path`` atomically.

    A failure is logged, not raised: the field works without its cache.
    """
    meta = dict(meta, version=CACHE_VERSION)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, meta=np.array(json.dumps(meta)), **{name.lstrip("_"): arrays[name] for name in ARRAYS})
        os.replace(tmp, path)          # atomic: a reader sees the old file or the new one
        tmp = None
    except OSError as exc:
        _log.warning("fast field: cannot write the cache %s: %s", path, exc)
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)


def read_cache(path, fingerprint, layout):
    """The arrays and figures of the cached field at ``path``; None (rebuild) if missing, stale or corrupt.

    Parameters
    ----------
    path : pathlib.Path
    fingerprint : str
        The field's (:func:`fingerprint`); another one means another geometry.
    layout : callable
        ``() -> (FieldParams, GridShape)``: the layout the arrays must have.

    Returns
    -------
    arrays : dict or None
        Name (as in :data:`ARRAYS`) -> array, mapped from the file (copy-on-write).
    meta : dict
        The file's record; its ``error_bound`` and ``measured_max_error`` checked.
    """
    if not path.is_file():
        return None, None
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
        if meta.get("version") != CACHE_VERSION or meta.get("fingerprint") != fingerprint:
            _log.info("fast field: cache %s is for another geometry or version; rebuilding", path)
            return None, None
        # mapped, not read: pages shared by every process that loads the field, read when touched
        mapped = map_npz(path, [name.lstrip("_") for name in ARRAYS])
        arrays = {name: mapped[name.lstrip("_")] for name in ARRAYS}
        fp, ip = arrays["_fp"], arrays["_ip"]
        if fp.shape != (len(FieldParams._fields),) or ip.shape != (len(GridShape._fields),) or ip.dtype != np.int64:
            raise ValueError("parameter vectors")
        shape = GridShape(*(int(v) for v in ip))
        nx, nr, nt = shape.nx, shape.nr, shape.nt
        ncx, ncr, nct = shape.ncx, shape.ncr, shape.nct
        expect = {"_grid": ((nx, nr, nt, 2), np.float32), "_hs": ((shape.nhx, shape.nhr, 2), np.float32),
                  "_line_uv": ((nx, nr, 2, 2), np.float64), "_coarse_uv": ((ncx, ncr, nct, 2, 2), np.float64),
                  "_kind": ((ncx - 1, ncr - 1, nct - 1, 2), np.uint8),
                  "_line_theta": ((nx, nr, 2), np.float64), "_line_inside": ((nx, nr, 2), np.bool_)}
        for name, (want, dtype) in expect.items():
            if arrays[name].shape != want or arrays[name].dtype != dtype:
                raise ValueError(f"{name}: {arrays[name].shape} {arrays[name].dtype}, expected {want}")
        ref_params, ref_shape = layout()
        if not (tuple(shape) == tuple(ref_shape) and np.allclose(fp, np.array(ref_params), rtol=0, atol=1e-9)):
            raise ValueError("grid layout differs")
        meta["error_bound"] = float(meta["error_bound"])
        meta["measured_max_error"] = {k: float(meta["measured_max_error"][k]) for k in SURFACES}
        if not (np.isfinite(meta["error_bound"]) and meta["error_bound"] >= 0):
            raise ValueError("error bound")
    except Exception as exc:     # noqa: BLE001 -- any unreadable cache means: rebuild
        _log.warning("fast field: cache %s unusable (%s); rebuilding", path, exc)
        return None, None
    return {name: np.ascontiguousarray(value) for name, value in arrays.items()}, meta
