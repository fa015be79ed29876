"""The benchmark suites by name (``python -m edm_planner.bench --only NAME``)."""

from .core import bench_geometry, bench_interference, bench_planning, bench_roughing
from .machining import bench_electrode_set
from .process import bench_process
from .scaleout import bench_scaleout
from .speed import bench_speed
from .step import bench_step

#: suite name -> function returning its JSON-able figures
SUITES = {"geometry": bench_geometry, "interference": bench_interference, "planning": bench_planning,
          "roughing": bench_roughing, "electrode_set": bench_electrode_set, "speed": bench_speed,
          "process": bench_process, "scaleout": bench_scaleout,
          "step": bench_step}

#: suites run only when named with --only: ``step`` fuses a 60-blade STEP solid the first time (about 17 min and
#: 8 GB of memory on the 2-core AMD EPYC; the file is cached after)
OPT_IN = frozenset({"step"})
