"""ament_python package edm_planner (works with colcon and with plain pip)."""

import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "edm_planner"

# One entry per node (edm_planner/nodes/entry.py: the node's main, then a quick exit); the executables land
# in lib/edm_planner (ros2 run) and, under pip, in the environment's bin/.
NODES = {
    "geometry_loader": "edm_planner.nodes.entry:geometry_loader",
    "interference_checker": "edm_planner.nodes.entry:interference_checker",
    "trajectory_planner": "edm_planner.nodes.entry:trajectory_planner",
    "axis_bridge": "edm_planner.nodes.entry:axis_bridge",
}

# Command-line tools (bin/ only, not ROS nodes).
COMMANDS = ["edm-plan = edm_planner.cli:run"]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
    ] + [
        # config/ and its data sub-directories, as they are
        (f"share/{PACKAGE}/{d}", sorted(f for f in glob(f"{d}/*") if os.path.isfile(f)))
        for d in sorted({os.path.dirname(f) for f in glob("config/**/*", recursive=True)} | {"config"})
    ],
    include_package_data=True,
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="edm_planner developers",
    maintainer_email="edm-planner@example.com",
    description="Five-axis EDM electrode path planning for integral shrouded blisks (ROS 2 Jazzy).",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in NODES.items()] + COMMANDS},
)
