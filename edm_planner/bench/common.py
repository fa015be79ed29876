"""What the benchmark suites share: the config directory, the electrode design and poses they measure with.

Also the designed sets the process suite reuses from the electrode-set suite when both run in one process.
"""

import pathlib
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.electrode import ElectrodeDesign

CONFIG = pathlib.Path(__file__).resolve().parents[2] / "config"


def best_of(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def rear_design():
    """The planning benchmark's electrode: the rear of a front/rear split (h = 0.03 rad, radial reduction 3 mm).

    The default blisk's primitive electrode cannot leave its channel; the
    planning, verification and speed suites all plan this one.
    """
    return ElectrodeDesign(circumferential_reduction=0.03, radial_reduction=3.0, split="front_rear",
                           split_overlap=1.0)


def poses_near(final_pose, n, seed=0, spread=0.05):
    """n electrode poses near the final pose (small random rigid motions)."""
    rng = np.random.default_rng(seed)
    poses = np.repeat(final_pose[None], n, axis=0)
    rot = Rotation.from_rotvec(rng.normal(scale=spread / 100.0, size=(n, 3))).as_matrix()
    poses[:, :3, :3] = rot @ final_pose[:3, :3]
    poses[:, :3, 3] += rng.normal(scale=spread, size=(n, 3))
    return poses


#: blisk name -> (geometry, set result) designed by the electrode-set suite, reused by the process suite
DESIGNED = {}

#: the blisks of the electrode-set and process suites
BLISKS = {"default_blisk": CONFIG / "default_blisk.yaml", "rotor37": CONFIG / "rotor37.yaml",
          "mesh_blisk": CONFIG / "mesh_blisk.yaml",
          "blisk72": CONFIG.parent / "test" / "cases" / "blisk72" / "geometry.yaml"}
