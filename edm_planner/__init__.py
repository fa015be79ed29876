"""edm_planner: electrode path planning for five-axis EDM of shrouded blisks.

The sub-packages ``geometry`` (and, later, ``interference``, ``planning``,
``machine``) are plain numpy/scipy/trimesh code without rclpy; ``nodes`` holds
the thin ROS 2 adapters.
"""

__version__ = "0.1.0"

import hashlib as _hashlib
import os as _os
import sys as _sys

#: the user's cache: distance fields (keyed by geometry id) and, under ``numba/``, compiled kernels
CACHE_ROOT = _os.path.join(_os.path.expanduser("~"), ".cache", "edm_planner")
#: where our compiled numba kernels are kept, one subdirectory per version of the kernel sources
NUMBA_CACHE_ROOT = _os.path.join(CACHE_ROOT, "numba")


def kernel_sources_digest(package=_os.path.dirname(__file__)):
    """A digest of every module of the package that mentions numba (about 2 ms).

    numba's cache checks a kernel against its own file's time stamp only, not
    against the files its compiled code was built from (the intrinsics in
    ``interference/cell_simd.py``, kernels of other modules it calls): after
    an edit there, the cached code would be stale. One cache directory per
    content of all kernel sources rules that out.
    """
    digest = _hashlib.sha256()
    for folder, subfolders, files in sorted(_os.walk(package)):
        subfolders.sort()
        for name in sorted(f for f in files if f.endswith(".py")):
            with open(_os.path.join(folder, name), "rb") as source:
                text = source.read()
            if b"numba" in text:
                digest.update(name.encode() + b"\0" + text)
    return digest.hexdigest()[:16]


# numba keeps the compiled kernels (``cache=True``) in a directory that survives runs and is shared by
# every process (nodes, the CLI, tests), so each kernel compiles once per machine and source version.
# Set before any module of ours defines a kernel; a NUMBA_CACHE_DIR given by the caller wins.
if "NUMBA_CACHE_DIR" not in _os.environ:
    _os.environ["NUMBA_CACHE_DIR"] = _os.path.join(NUMBA_CACHE_ROOT, kernel_sources_digest())
# numba's parallel kernels run on OpenMP, whose idle threads spin by default: with several processes at once
# (the nodes, the set designer's workers) spinning threads take the cores from the ones that work. Sleep
# instead (read when the OpenMP runtime starts, i.e. at the first parallel kernel call).
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
if "numba" in _sys.modules:          # imported before us: it read its configuration already
    _sys.modules["numba"].core.config.reload_config()
