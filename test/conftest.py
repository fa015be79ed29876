"""Test configuration: loopback DDS and a ROS domain of this run's own."""

import faulthandler
import importlib
import os
import pathlib
import sys
import threading

import pytest

# Before anything initialises rclpy: keep DDS on this machine and away from
# other test runs (a domain from the process id, unless the caller set one).
# Under pytest-xdist each worker inherits the controller's domain and moves to
# one of its own (worker gw<i>: + step i, within 1..100), so the workers' nodes never meet. The steps keep
# every pair of workers apart by none of the differences the tests' own domains make (the demo's + 101 and
# + 103, the bring-up's + 157 and + 171, modulo 232: 2, 14, 54, 56, 61, 68, 70, 75).
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
WORKER_STEP = {1: 0, 2: 50, 3: 33, 4: 20, 5: 20}
if WORKER:
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "2"))
    if count not in WORKER_STEP:
        raise RuntimeError(f"{count} pytest-xdist workers: the ROS domains of this suite are laid out for 1 to 5")
    os.environ["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) - 1 + WORKER_STEP[count] * int(WORKER[2:]))
                                      % 100 + 1)
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
# The suite is an entry point: before anything initialises rclpy or imports a kernel module, the process
# set-up the nodes do (edm_planner/ros/startup.py): DDS on loopback UDP in this process and every child it
# starts (Fast DDS's shared memory can hang a node started after one that was killed), and the compiled numba
# kernels in the user's cache, one directory per version of the kernel sources, named in NUMBA_CACHE_DIR so
# that processes started with another HOME (the demo's fresh user) still find them.
importlib.import_module("edm_planner.ros.startup").prepare_process()

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
REPO = pathlib.Path(__file__).resolve().parent.parent
CONFIG = REPO / "config"


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: plans over DDS, node processes, the whole product (make test runs them, "
                                       "make test-fast leaves them out)")


#: the files that run longest, started first: with one file per worker (``--dist loadfile``, files handed
#: out in collection order) a long file started last keeps one core busy alone at the end of the run
#: (test_cpu_variants.py: 10 s with numba's cache of the other CPU, 2 to 2.5 min on a new clone, which has none)
LONG_FILES = ("test_colcon_workspace.py", "test_certificate_truth.py", "test_fuzz_services.py",
              "test_electrode_set_node.py", "test_cpu_variants.py", "test_blisk_plan.py", "test_demo.py",
              "test_step_import.py",
              "test_planner.py", "test_ray_scaleout.py", "test_machining_cycle.py", "test_blisk_program.py",
              "test_cycle_execution.py", "test_blisk_scan.py", "test_set_piece_cycle.py",
              "test_exact_verification.py", "test_actions.py", "test_plan_export.py")


#: seconds before a test's deadline at which the stacks of its children are printed (they are killed after)
CHILD_REPORT_MARGIN = 20.0
#: seconds after the deadline at which a test process stuck in C code (pytest-timeout's alarm cannot run while a
#: C call holds the interpreter) prints every thread's stack from faulthandler's own thread and exits
HARD_EXIT_MARGIN = 60.0


def _deadline(item):
    marker = item.get_closest_marker("timeout")
    if marker is not None and marker.args:
        return float(marker.args[0])
    value = item.config.getini("timeout")
    return float(value) if value else 0.0


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Every test has a deadline (pytest-timeout); near it the children's stacks, past it a hard exit with stacks."""
    from hang_report import report_children

    deadline = _deadline(item)
    timer = None
    if deadline > 0:
        timer = threading.Timer(max(deadline - CHILD_REPORT_MARGIN, 1.0), report_children)
        timer.daemon = True
        timer.start()
        faulthandler.dump_traceback_later(deadline + HARD_EXIT_MARGIN, exit=True)
    try:
        yield
    finally:
        if timer is not None:
            timer.cancel()
            faulthandler.cancel_dump_traceback_later()


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONG_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONG_FILES)))      # stable: in-file order kept


@pytest.fixture
def ros():
    """Nodes in-process on a private context; see ros_harness.InProcessRos."""
    from ros_harness import InProcessRos

    harness = InProcessRos()
    try:
        yield harness
    finally:
        harness.close()


@pytest.fixture
def node_processes(tmp_path):
    """Nodes as OS processes; stopped (SIGINT, then SIGKILL) at teardown."""
    from ros_harness import NodeProcesses

    procs = NodeProcesses(tmp_path / "logs")
    try:
        yield procs
    finally:
        procs.stop()


def run_directory(tmp_path_factory):
    """The run's temporary directory, shared by all pytest-xdist workers (each has a basetemp below it)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if WORKER else base


@pytest.fixture(scope="session")
def field_cache(tmp_path_factory):
    """One distance-field cache directory for the whole run (shared by the xdist workers).

    Each geometry's field is built once and written atomically; a worker that finds it loads it.
    """
    path = run_directory(tmp_path_factory) / "field_cache"
    path.mkdir(exist_ok=True)
    return str(path)


@pytest.fixture(scope="session")
def default_geometry():
    """config/default_blisk.yaml loaded once per test process (treat as read-only)."""
    from edm_planner.geometry.loader import load_geometry

    return load_geometry(CONFIG / "default_blisk.yaml")


@pytest.fixture(scope="session")
def default_field(default_geometry, field_cache):
    """The default blisk's distance field at the planner's spacing (0.1 mm), from the run's field cache."""
    from edm_planner.interference.fast import FastChannelField

    g = default_geometry
    # one xdist worker builds it, the other waits for the field's build lock and loads it
    return FastChannelField(g.blisk, spacing=0.1, cache_dir=field_cache, cache_key=g.geometry_id)


@pytest.fixture(scope="session", autouse=True)
def plan_store_of_this_run(tmp_path_factory):
    """Nodes and the CLI keep plans in a store of this run, not in the user's (EDM_PLANNER_PLAN_STORE)."""
    path = str(tmp_path_factory.mktemp("plan_store"))
    os.environ["EDM_PLANNER_PLAN_STORE"] = path
    return path


#: the electrode whose cycle the machining tests share: the rear of a front/rear split, exits downstream
REAR_GAP, REAR_TOLERANCE = 0.1, 0.02


@pytest.fixture(scope="session")
def rear_cycle(default_geometry, default_field):
    """(geometry, field, electrode, design, plan with its certified cycle, cycle builder), planned once per process.

    The plan is certified with the machining margin (gap less the tolerance). Tests that change the plan
    take ``copy.deepcopy`` of it.
    """
    from edm_planner.geometry.electrode import ElectrodeDesign, design_electrodes
    from edm_planner.machining.cycle import CycleBuilder, CycleOptions
    from edm_planner.planning.plan import PlanOptions
    from edm_planner.planning.planner import plan_channel
    from edm_planner.planning.search import SearchOptions

    g, field = default_geometry, default_field
    design = ElectrodeDesign(circumferential_reduction=0.03, radial_reduction=3.0, split="front_rear",
                             split_overlap=1.0)
    margin = REAR_GAP - REAR_TOLERANCE
    electrode = design_electrodes(g.blisk, design, only="rear")[0]
    opts = PlanOptions(search=SearchOptions(margin_blade=margin, margin_hub_shroud=margin, exit_side="downstream"))
    plan = plan_channel(g, 0, "rear", opts, field=field, design=design, electrodes=[electrode])
    assert plan.success, plan.message
    builder = CycleBuilder(field, electrode, design, plan.axis_names, CycleOptions(tolerance=REAR_TOLERANCE))
    plan.cycle = builder.build(plan.samples, margin, plan.metrics.clearance_lower_bound)
    assert plan.cycle.certified, plan.cycle.message
    return g, field, electrode, design, plan, builder
