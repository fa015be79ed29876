"""edm_planner: electrode path planning for five-axis EDM of shrouded blisks.

Layers, top to bottom (a contract import-linter checks, ``.importlinter``):

* entry points: :mod:`.bench`; :mod:`.apps` and :mod:`.cli`; :mod:`.nodes` (the ROS 2 nodes and, in
  :mod:`.nodes.programs`, the programs that drive them) over :mod:`.ros` (their shared rclpy parts); only
  these last two import rclpy;
* :mod:`.records`: the plan store, the certificate digest, exports, plots;
* the domain, plain numpy/scipy/trimesh/numba without rclpy: :mod:`.process`, :mod:`.machining`,
  :mod:`.planning` and :mod:`.roughing`, :mod:`.cnc` and :mod:`.interference`, :mod:`.geometry`;
* the base: :mod:`.errors`, :mod:`.constants`, :mod:`.paths`, :mod:`.environment`.

Importing the package has no side effects; entry points call
:func:`edm_planner.environment.configure_process` first.
"""

__version__ = "0.1.0"

# kept importable from the package: the cache locations and the kernel digest live in .environment
from .environment import CACHE_ROOT, NUMBA_CACHE_ROOT, kernel_sources_digest

__all__ = ["__version__", "CACHE_ROOT", "NUMBA_CACHE_ROOT", "kernel_sources_digest"]
