"""The set-up of a process that runs rclpy: the core's (numba's cache, OpenMP) and Fast DDS on loopback."""

from ..environment import configure_process
from .dds import use_loopback_udp


def prepare_process():
    """Set up this process before ``rclpy.init``: :func:`~edm_planner.environment.configure_process`, then
    :func:`~.dds.use_loopback_udp` (Fast DDS on loopback UDP, never shared memory, where LOCALHOST discovery
    is asked for). Idempotent; every node's ``main`` and every program of :mod:`edm_planner.nodes.programs`
    that starts rclpy calls it first.

    Returns
    -------
    str
        What was done to DDS (:func:`~.dds.use_loopback_udp`).
    """
    configure_process()
    return use_loopback_udp()
