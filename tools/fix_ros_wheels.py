"""Rewrite the build-machine paths in the ROS wheels' exported CMake files.

The ros-jazzy-* wheels were built under /opt/python/cp311-cp311; their
``share/*/cmake/*.cmake`` files name that interpreter's include and
site-packages directories, and CMake's generate step fails on the missing
paths (see ../shared/ROS_WHEELS.md). Idempotent: files already fixed are left.
"""

import pathlib
import sys
import sysconfig

BUILD_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILD_SITE = "/opt/python/cp311-cp311/lib/python3.11/site-packages"


def main() -> int:
    prefix = pathlib.Path(sys.prefix)
    paths = sysconfig.get_paths()
    changed = 0
    for f in prefix.glob("share/*/cmake/*.cmake"):
        text = f.read_text()
        if BUILD_INCLUDE in text or BUILD_SITE in text:
            f.write_text(text.replace(BUILD_INCLUDE, paths["include"]).replace(BUILD_SITE, paths["purelib"]))
            changed += 1
    print(f"fix_ros_wheels: rewrote {changed} CMake file(s) under {prefix}/share")
    return 0


if __name__ == "__main__":
    sys.exit(main())
