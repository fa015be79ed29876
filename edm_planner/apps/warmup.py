"""Compile every numba kernel once, into numba's on-disk cache, before parallel work starts.

numba compiles a kernel on its first call in a process and caches it on disk
(``cache=True``, ``NUMBA_CACHE_DIR``: one directory per version of the
kernel sources, see :mod:`edm_planner.environment`). A fresh clone or a changed
kernel starts empty; processes started together (the nodes of ``make demo``,
the set designer's workers, the test workers) would then each compile the
same kernels at once. This
module makes one process compile them all first, through the public API and
the same argument types as real work: the default blisk's electrode design
(spline kernels), a coarse distance field (fill and query kernels), the exact
re-check of a few poses (branch and bound) and a small removal proof.

``python -m edm_planner.apps.warmup`` (``make setup`` runs it); a second run finds
everything cached and takes a few seconds. No rclpy.
"""

import argparse
import logging
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

from .. import environment

# this entry point's set-up, before the core's kernel modules load (numba reads its cache directory then)
environment.configure_process()

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from ..geometry.loader import load_geometry  # noqa: E402  (after the set-up above)
from ..interference.fast import FastChannelField  # noqa: E402
from ..interference.pose_check import verify_poses  # noqa: E402
from ..machining.removal import stock_at_points  # noqa: E402
from ..process.report import silhouette_area  # noqa: E402
from ..process.volume import AnnulusBlank, Cut, removed_volumes  # noqa: E402

CONFIG = pathlib.Path(__file__).resolve().parent.parent / "config"
_log = logging.getLogger(__name__)


def _config_dir():
    """The repository's config, or the installed share directory's."""
    if (CONFIG / "default_blisk.yaml").exists():
        return CONFIG
    return pathlib.Path(sys.prefix) / "share" / "edm_planner" / "config"


def warm_up(part=None, cache_dir=None):
    """Run a small piece of every kind of work once; returns the seconds it took.

    ``part`` 0 or 1 does half of it (run both at once in two processes with
    one ``cache_dir``: part 0 builds the coarse field, part 1 loads it under
    the field's build lock); None does all.
    """
    t0 = time.perf_counter()
    g = load_geometry(_config_dir() / "default_blisk.yaml")            # electrode design: spline kernels
    e = g.electrodes[0]
    vertices = np.asarray(e.mesh.vertices)[::50]
    poses = np.repeat(e.final_pose[None], 3, axis=0)
    poses[:, 0, 3] += np.array([0.0, 2.0, 40.0])                       # in the channel, and past the blades
    world = vertices @ e.final_pose[:3, :3].T + e.final_pose[:3, 3]
    if part in (None, 1):                                               # the removal proof's kernels
        mesh = e.mesh
        stock_at_points(world[:200], [(np.asarray(mesh.vertices), np.asarray(mesh.faces), poses[:2])], 0.1)
    if part in (None, 0):                                               # the process: volume field, silhouettes
        box = trimesh.creation.box((4.0, 2.0, 3.0))
        pose = np.eye(4)
        pose[:3, 3] = (10.0, 0.0, 110.0)
        removed_volumes(AnnulusBlank.from_blisk(g.blisk), [Cut("warm-up", np.asarray(box.vertices),
                                                               np.asarray(box.faces), pose[None], 0.1)], 1.0)
        silhouette_area(np.asarray(box.vertices), np.asarray(box.faces), (1.0, 0.0, 0.0), pixel=0.5)
    with tempfile.TemporaryDirectory() as tmp:
        field = FastChannelField(g.blisk, spacing=0.6, cache_dir=cache_dir or tmp, cache_key="warm-up",
                                 error_samples=300)
    for channel in (0, 1):
        if part in (None, 1):                                           # the queries
            field.clearances(world, channel)
            field.fast_path(world, channel)
            field.exact_blade_distances(world[:20], channel)
            field.pose_clearances(poses, vertices, channel)
            field.posed_clearances(poses, vertices, channel)
        if part in (None, 0):                                           # the exact solvers and the re-check
            field.exact_blade_feet(world[:20], channel)
            field.behind_walls(world[:20], channel)
            field.exact_pose_clearances(poses[:1], vertices[:20], channel)
    if part in (None, 0):
        field.exact_profile_distances(world[:20])
        verify_poses(poses[:2], vertices, 0, g.blisk, field)
    spent = time.perf_counter() - t0
    _log.info(f"warm-up{'' if part is None else f' (part {part})'}: numba kernels compiled or loaded from "
        f"the cache in {spent:.1f} s")
    return spent


def main(argv=None):
    parser = argparse.ArgumentParser(description="compile edm_planner's numba kernels into the cache")
    parser.add_argument("--part", type=int, choices=(0, 1))
    parser.add_argument("--cache-dir")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
    if args.part is not None:
        warm_up(args.part, args.cache_dir)
        return 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:                          # two processes, one field between them
        procs = [subprocess.Popen([sys.executable, "-m", "edm_planner.apps.warmup", "--part", str(p), "--cache-dir", tmp])
                 for p in (0, 1)]
        codes = [p.wait() for p in procs]
    if any(codes):
        _log.error("warm-up failed (exit codes %s)", codes)
        return 1
    _log.info("warm-up: done in %.1f s", time.perf_counter() - t0)
    for old in prune_kernel_caches():
        _log.info("warm-up: removed %s (kernels of other sources, unused for %d days)", old, KEEP_DAYS)
    return 0


#: how long the kernels compiled from other versions of the sources are kept (another clone may use them)
KEEP_DAYS = 30


def prune_kernel_caches(now=None):
    """Remove the numba cache directories of other kernel sources nothing wrote to for ``KEEP_DAYS``.

    Each version of the kernel sources gets its own directory under
    ``edm_planner.environment.NUMBA_CACHE_ROOT`` (about 90 MB); only the default root is
    pruned, never a NUMBA_CACHE_DIR the caller chose. Returns what was removed.
    """
    root, current = pathlib.Path(environment.NUMBA_CACHE_ROOT), pathlib.Path(os.environ["NUMBA_CACHE_DIR"])
    if current.parent != root or not root.is_dir():
        return []
    limit = (time.time() if now is None else now) - KEEP_DAYS * 86400
    removed = []
    for entry in root.iterdir():
        if entry == current or not entry.is_dir():
            continue
        newest = max((p.stat().st_mtime for p in entry.rglob("*")), default=entry.stat().st_mtime)
        if newest < limit:
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed


if __name__ == "__main__":
    raise SystemExit(main())
