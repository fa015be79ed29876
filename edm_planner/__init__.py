"""edm_planner: electrode path planning for five-axis EDM of shrouded blisks.

The sub-packages ``geometry`` (and, later, ``interference``, ``planning``,
``machine``) are plain numpy/scipy/trimesh code without rclpy; ``nodes`` holds
the thin ROS 2 adapters.
"""

__version__ = "0.1.0"

import os as _os
import sys as _sys

# numba keeps the compiled kernels (``cache=True``) in a directory that survives runs and is shared by
# every process (nodes, the CLI, tests), so each kernel compiles once per machine and source version.
# Set before any module of ours defines a kernel; a NUMBA_CACHE_DIR given by the caller wins.
_os.environ.setdefault("NUMBA_CACHE_DIR", _os.path.join(_os.path.expanduser("~"), ".cache", "edm_planner", "numba"))
# numba's parallel kernels run on OpenMP, whose idle threads spin by default: with several processes at once
# (the nodes, the set designer's workers) spinning threads take the cores from the ones that work. Sleep
# instead (read when the OpenMP runtime starts, i.e. at the first parallel kernel call).
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
if "numba" in _sys.modules:          # imported before us: it read its configuration already
    _sys.modules["numba"].core.config.reload_config()
