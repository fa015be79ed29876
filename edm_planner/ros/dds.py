"""DDS set-up of every process the project runs: loopback UDP instead of Fast DDS shared memory.

With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, rmw_fastrtps (Jazzy) adds
Fast DDS's shared-memory transport beside UDP. Its ports are guarded by
boost interprocess mutexes in ``/dev/shm``: a participant killed (or
racing another) while it creates or holds one leaves it behind, and every
participant started later spins forever in ``rclpy.create_node``
(``SharedMemGlobal::open_port_internal``), with nothing in its log. A
cell restarts crashed nodes, so that is a hang waiting to happen.

:func:`use_loopback_udp` keeps LOCALHOST's promise (nothing leaves the
machine) on a transport with no state shared between processes: it points
Fast DDS at ``config/dds/fastdds_loopback_udp.xml`` (UDPv4 bound to
127.0.0.1, unicast discovery to 127.0.0.1, no multicast, no shared memory)
and tells rmw_fastrtps to leave the transports to that profile
(``SYSTEM_DEFAULT`` range in this process and its children). It must run
before the process's first ``rclpy.init``; ``edm_planner.nodes`` calls it on
import, which every entry point of ours does first. Other middlewares, other
ranges and a profile of the user's own are left alone;
``EDM_PLANNER_DDS=stock`` turns it off. No rclpy here: environment only.
"""

import logging
import os
import pathlib

_log = logging.getLogger(__name__)

PROFILE_NAME = "fastdds_loopback_udp.xml"
#: the environment variables Fast DDS reads its default XML profile from (2.x and 3.x names)
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def profile_path():
    """The loopback-UDP profile: the source tree's ``config/dds`` or the installed ``share/edm_planner``.

    Returns
    -------
    pathlib.Path or None
        None when neither holds it (a broken install).
    """
    here = pathlib.Path(__file__).resolve()
    candidates = [here.parents[2] / "config" / "dds" / PROFILE_NAME]
    try:
        # optional here: the set-up runs in processes without the ROS wheels too (the docs build, a bare pip
        # install of the core); the source tree's profile serves them
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            candidates.append(pathlib.Path(get_package_share_directory("edm_planner")) / "config" / "dds"
                              / PROFILE_NAME)
        except (PackageNotFoundError, OSError):     # not installed, or no AMENT_PREFIX_PATH
            pass
    except ImportError:
        pass
    return next((p for p in candidates if p.is_file()), None)


def _same_profile(path, profile):
    """Whether ``path`` is our loopback profile (same name and content as ``profile``)."""
    if profile is None or os.path.basename(path) != PROFILE_NAME:
        return False
    try:
        return pathlib.Path(path).read_bytes() == profile.read_bytes()
    except OSError:
        return False


def wants_localhost(environ):
    """Whether the caller asked for discovery on this machine only (the range, or the older ROS_LOCALHOST_ONLY)."""
    wanted = environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
    return wanted == "LOCALHOST" or (not wanted and environ.get("ROS_LOCALHOST_ONLY", "").strip() == "1")


def use_loopback_udp(environ=None):
    """Switch this process (and the children it starts) to the loopback-UDP profile where LOCALHOST was asked.

    Parameters
    ----------
    environ : mutable mapping, optional
        The environment to change (``os.environ``).

    Returns
    -------
    str
        What was done: ``"loopback-udp"`` (switched, or already switched by a parent), or why not
        (``"stock: ..."``).
    """
    env = os.environ if environ is None else environ
    profile = profile_path()
    current = {env.get(v) for v in PROFILE_VARIABLES} - {None, ""}
    # ours: this install's profile, or the same file of another install (a colcon workspace's nodes started
    # from a process of the source tree inherit its path)
    ours = {c for c in current if _same_profile(c, profile)} | ({str(profile)} if profile is not None else set())
    if env.get("EDM_PLANNER_DDS", "").strip().lower() == "stock":
        return "stock: EDM_PLANNER_DDS=stock"
    if env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        return f"stock: the middleware is {env['RMW_IMPLEMENTATION']}"
    if current and current <= ours and env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "SYSTEM_DEFAULT":
        return "loopback-udp"                                   # a parent of ours set it up
    if not wants_localhost(env):
        return "stock: discovery beyond this machine was asked for (ROS_AUTOMATIC_DISCOVERY_RANGE)"
    if current - ours:
        _log.warning("DDS: the Fast DDS profile %s is the user's own; with LOCALHOST discovery rmw_fastrtps adds "
                     "shared memory to it (a crashed node can then hang the nodes started after it)",
                     sorted(current - ours)[0])
        return "stock: the user's own Fast DDS profile"
    if profile is None:
        _log.warning("DDS: %s is missing from this install; staying on rmw_fastrtps's LOCALHOST set-up "
                     "(shared memory: a crashed node can hang the nodes started after it)", PROFILE_NAME)
        return "stock: the loopback profile is not installed"
    for variable in PROFILE_VARIABLES:
        env[variable] = str(profile)
    # rmw_fastrtps's LOCALHOST mode would replace the profile's transports by shared memory + UDP
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
    env.pop("ROS_LOCALHOST_ONLY", None)
    return "loopback-udp"


def loopback_unless_told(environ=None):
    """Our programs (soak, benches, drills) keep DDS on this machine unless the caller chose a range: LOCALHOST by
    default, then :func:`use_loopback_udp`."""
    env = os.environ if environ is None else environ
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return use_loopback_udp(env)
