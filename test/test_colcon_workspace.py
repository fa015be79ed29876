"""A ROS 2 user's colcon workspace: the repository in ws/src, built with real colcon, a node run from the install space.

The steps of README.md ("On a real ROS 2 Jazzy install"), with the wheels of .venv as the underlay
(``tools/ros_underlay.bash`` in place of ``/opt/ros/jazzy/setup.bash``): the repository's files in
``ws/src/edm_planner``, ``colcon build --base-paths src src/edm_planner/msg_defs`` (colcon's crawl
stops at the repository's own package.xml, so the nested interface package is named as a second base
path), ``source install/setup.bash``, and the executable ``ros2 run edm_planner geometry_loader``
runs (``install/edm_planner/lib/edm_planner/geometry_loader``) answering LoadGeometry over DDS.
.venv holds an ``edm_planner_msgs`` of its own (make setup builds it there): every check below
tells the install space's from it.
"""

import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pytest
from edm_planner_msgs.srv import LoadGeometry
from rclpy.node import Node

from conftest import REPO
from user_shell import run_in_shell, shell_command, user_environment

pytestmark = pytest.mark.slow

#: the README's build command, run in the workspace root
BUILD = "colcon build --base-paths src src/edm_planner/msg_defs"
BUILD_TIMEOUT = 1200        # about 40 s idle on the two cores, 1-1.5 min under load
PYTHON = f"python{sys.version_info.major}.{sys.version_info.minor}"


def copy_repository(dest):
    """The files a clone of the repository holds (tracked, and new files not ignored), as the work tree has them."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            cwd=REPO, capture_output=True, text=True, check=True, timeout=120).stdout.split("\0")
    count = 0
    for rel in filter(None, listed):
        src = REPO / rel
        if not src.is_file():       # deleted in the work tree
            continue
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / rel)
        count += 1
    return count


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """ws/ with the repository in src/edm_planner, built once for this module with the README's command."""
    ws = pathlib.Path(os.path.realpath(tmp_path_factory.mktemp("colcon_ws")))     # as /proc/<pid>/maps names it
    assert copy_repository(ws / "src" / "edm_planner") > 20
    t0 = time.monotonic()
    build = run_in_shell(ws, BUILD, overlay=False, timeout=BUILD_TIMEOUT)
    (ws / "build_output.log").write_text(build.stdout + build.stderr)
    assert build.returncode == 0, f"{BUILD} failed:\n{build.stdout[-4000:]}\n{build.stderr[-4000:]}"
    print(f"\n{BUILD}: {time.monotonic() - t0:.0f} s")
    return ws


def test_plain_colcon_stops_at_the_repository_package_and_the_base_paths_find_both(workspace):
    """Why the README's command names msg_defs: colcon's crawl does not look inside a package it identified."""
    listed = run_in_shell(workspace, "colcon list --names-only && echo --- && "
                                     "colcon list --names-only --base-paths src src/edm_planner/msg_defs",
                          overlay=False)
    assert listed.returncode == 0, listed.stderr
    plain, with_base_paths = (part.split() for part in listed.stdout.split("---"))
    assert plain == ["edm_planner"]
    assert with_base_paths == ["edm_planner", "edm_planner_msgs"]


def test_both_packages_are_installed_in_the_ament_layout(workspace):
    install = workspace / "install"
    for pkg in ("edm_planner", "edm_planner_msgs"):
        assert (install / pkg / "share" / "ament_index" / "resource_index" / "packages" / pkg).is_file()
        assert (install / pkg / "share" / pkg / "package.xml").is_file()
    assert os.access(install / "edm_planner" / "lib" / "edm_planner" / "geometry_loader", os.X_OK)
    assert (install / "edm_planner" / "share" / "edm_planner" / "config" / "default_blisk.yaml").is_file()
    assert (install / "edm_planner_msgs" / "lib" / "libedm_planner_msgs__rosidl_typesupport_c.so").is_file()


PROBE = """
import json, edm_planner, edm_planner_msgs
from edm_planner_msgs.srv import LoadGeometry
from rclpy.type_support import check_for_type_support
check_for_type_support(LoadGeometry)        # loads the type support's C libraries
from ament_index_python.packages import get_package_share_directory
libs = sorted({line.split()[-1] for line in open("/proc/self/maps") if "edm_planner_msgs" in line.split()[-1]})
print(json.dumps({"edm_planner": edm_planner.__file__, "edm_planner_msgs": edm_planner_msgs.__file__, "libs": libs,
                  "share": get_package_share_directory("edm_planner")}))
"""


def test_the_sourced_workspace_imports_both_packages_from_the_install_space(workspace, tmp_path):
    install = str(workspace / "install")
    (tmp_path / "probe.py").write_text(PROBE)
    probe = run_in_shell(workspace, f"python3 {tmp_path / 'probe.py'}")
    assert probe.returncode == 0, probe.stderr
    found = json.loads(probe.stdout.strip().splitlines()[-1])
    assert found["edm_planner"].startswith(os.path.join(install, "edm_planner", "lib")), found
    assert found["edm_planner_msgs"].startswith(os.path.join(install, "edm_planner_msgs", "lib")), found
    assert found["share"] == os.path.join(install, "edm_planner", "share", "edm_planner")
    assert found["libs"] and all(lib.startswith(install) for lib in found["libs"]), found["libs"]
    assert os.path.join(install, "edm_planner_msgs", "lib", "libedm_planner_msgs__rosidl_typesupport_c.so") \
        in found["libs"]


def wait_for_service(client, name, proc, log, timeout=600):
    """Wait until the service is available (the node loads the default blisk first), or the process has ended."""
    deadline = time.monotonic() + timeout
    while not client.wait_for_service(timeout_sec=1.0):
        assert proc.poll() is None, f"node exited with {proc.returncode}:\n{log.read_text()}"
        assert time.monotonic() < deadline, f"{name} not available after {timeout} s:\n{log.read_text()}"


def test_the_node_from_the_install_space_answers_load_geometry_over_dds(workspace, ros, tmp_path):
    """``ros2 run edm_planner geometry_loader`` of the workspace: its answer and its memory name the install space."""
    install = workspace / "install"
    exe = install / "edm_planner" / "lib" / "edm_planner" / "geometry_loader"
    env = user_environment()
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba")      # the install space's kernels are new source files
    log = tmp_path / "geometry_loader.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(shell_command(workspace, f"exec {exe}"), env=env, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        node = ros.add(Node("colcon_workspace_client", context=ros.context))
        wait_for_service(node.create_client(LoadGeometry, "load_geometry"), "load_geometry", proc, log)

        res = ros.call(node, LoadGeometry, "load_geometry", LoadGeometry.Request(path="default_blisk.yaml"), 120)
        assert res.success, f"{res.message}\n{log.read_text()}"
        assert res.summary.blade_count == 60
        # the node's configuration directory is the install space's share/ (the ament index of
        # install/setup.bash): the repository's own copy of the same file is outside it
        outside = str(REPO / "config" / "default_blisk.yaml")
        res = ros.call(node, LoadGeometry, "load_geometry", LoadGeometry.Request(path=outside), 120)
        assert not res.success
        assert str(install / "edm_planner" / "share" / "edm_planner" / "config") in res.message, res.message

        # the install space's node runs DDS on loopback UDP too (its own copy of the profile, found by the ament
        # index): every UDP socket it holds is bound to 127.0.0.1
        from edm_planner.nodes.programs.crash_drill import udp_local_addresses
        bound = udp_local_addresses(proc.pid)
        assert bound == {"127.0.0.1"}, f"the install space's node binds UDP to {bound}\n{log.read_text()}"

        # the process that answered: the interfaces' C libraries and Python extensions of the install space
        with open(f"/proc/{proc.pid}/maps") as maps:
            libs = sorted({line.split()[-1] for line in maps if "edm_planner_msgs" in line.split()[-1]})
        assert libs and all(lib.startswith(str(install)) for lib in libs), libs
        msgs_lib = install / "edm_planner_msgs" / "lib"
        for name in ("rosidl_typesupport_c", "rosidl_typesupport_fastrtps_c"):
            assert str(msgs_lib / f"libedm_planner_msgs__{name}.so") in libs, libs
        assert any(lib.startswith(str(msgs_lib / PYTHON / "site-packages" / "edm_planner_msgs")) for lib in libs), libs
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode in (0, -signal.SIGINT), log.read_text()


def test_a_plain_colcon_build_with_the_readmes_workspace_defaults_builds_both(workspace):
    """README: ``ws/colcon_defaults.yaml`` makes a plain ``colcon build`` name the same base paths (rebuilt: seconds)."""
    defaults = workspace / "colcon_defaults.yaml"
    defaults.write_text("build: {base-paths: [src, src/edm_planner/msg_defs]}\n")
    try:
        build = run_in_shell(workspace, "colcon build", overlay=False, timeout=BUILD_TIMEOUT)
    finally:
        defaults.unlink()
    assert build.returncode == 0, f"{build.stdout[-4000:]}\n{build.stderr[-4000:]}"
    finished = {line.split()[2] for line in build.stdout.splitlines() if line.startswith("Finished <<< ")}
    assert finished == {"edm_planner", "edm_planner_msgs"}, build.stdout
