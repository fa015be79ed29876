"""Designed electrodes kept on disk by content: the same blisk, design and code give the same electrodes.

Designing an electrode (its walls offset by the discharge gap through closest points on the blade faces)
takes 0.5 to 1.2 s on a 2-core cell PC. A cell plans every channel of a blisk with one design, each plan a
new ``edm-plan plan`` process, and a node designs again after every start. So :func:`cached_design` keeps
the electrodes under ``<cache_dir>/electrodes/``, keyed by a digest of

* the blisk as the nodes exchange it (``Blisk.to_dict``: a blisk as measured, per channel, has its own),
* the design (``ElectrodeDesign.to_dict``) and which electrode (``only``),
* every source file of the package (:func:`~edm_planner.environment.package_sources_digest`): any change of
  code designs anew.

A file is written whole or not at all (a temporary file, then a rename); one that cannot be read is designed
again and replaced; the newest ``KEEP`` files are kept. A cache that cannot be written costs the design only,
never the answer. Units: mm, rad.
"""

import logging
import pathlib
import zipfile

import numpy as np
import trimesh

from .disk_cache import content_key, get_or_make, write_whole
from .electrode import Electrode, ElectrodeDesign, design_electrodes

_log = logging.getLogger(__name__)

#: the file format; a new one designs every electrode again
FORMAT = "edm_planner.electrodes/1"

#: files kept in the cache directory (the least recently used go first); an electrode is about 1 MB
KEEP = 64

#: the sample sets of an electrode (``Electrode.samples``), in the order they are stored
SAMPLE_SETS = ("left", "right", "lower", "upper")


def design_key(blisk, design=None, only=None):
    """The cache key of ``design_electrodes(blisk, design, only=only)`` (hex sha256)."""
    return content_key({"format": FORMAT, "blisk": blisk.to_dict(),
                        "design": (design or ElectrodeDesign()).to_dict(), "only": only})


def cached_design(blisk, design=None, *, cache_dir, only=None, keep=KEEP):
    """``design_electrodes(blisk, design, only=only)``, from ``cache_dir`` when it holds them (None: no cache).

    Returns
    -------
    list of Electrode
        Bit for bit those ``design_electrodes`` gives: vertices, faces, final pose and samples.
    """
    if not cache_dir:
        return design_electrodes(blisk, design, only=only)
    path = pathlib.Path(cache_dir) / "electrodes" / f"{design_key(blisk, design, only)[:32]}.npz"
    return get_or_make(path, read_electrodes, lambda: design_electrodes(blisk, design, only=only),
                       _write_arrays, keep=keep, what="electrode")


def write_electrodes(path, electrodes):
    """Write electrodes to ``path`` (.npz) whole: a temporary file in the same folder, then a rename."""
    write_whole(path, lambda out: _write_arrays(out, electrodes))


def _write_arrays(out, electrodes):
    """The electrodes' arrays into the binary file ``out`` (a file object: savez adds no suffix)."""
    arrays = {"format": np.array(FORMAT), "ids": np.array([e.electrode_id for e in electrodes])}
    for i, e in enumerate(electrodes):
        arrays[f"vertices_{i}"] = np.asarray(e.mesh.vertices, dtype=np.float64)
        arrays[f"faces_{i}"] = np.asarray(e.mesh.faces, dtype=np.int64)
        arrays[f"pose_{i}"] = np.asarray(e.final_pose, dtype=np.float64)
        for name in SAMPLE_SETS:
            arrays[f"{name}_{i}"] = np.asarray(e.samples[name], dtype=np.float64)
    np.savez(out, **arrays)


def read_electrodes(path):
    """The electrodes in ``path``; None when it is missing, of another format or unreadable (logged)."""
    path = pathlib.Path(path)
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["format"]) != FORMAT:
                return None
            electrodes = []
            for i, electrode_id in enumerate(data["ids"]):
                mesh = trimesh.Trimesh(data[f"vertices_{i}"], data[f"faces_{i}"], process=False)
                samples = {name: data[f"{name}_{i}"] for name in SAMPLE_SETS}
                electrodes.append(Electrode(str(electrode_id), mesh, data[f"pose_{i}"], samples))
            return electrodes
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        _log.warning("electrode cache %s: unreadable (%s); designing the electrodes again", path, exc)
        return None

