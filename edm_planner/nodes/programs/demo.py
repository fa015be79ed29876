"""``make demo``: the whole product once, as a cell controller drives it over DDS.

Starts the four nodes as separate processes (launch-free bring-up, :mod:`.bringup`), then
LoadGeometry (the built-in default blisk) -> the PlanElectrodeSet action
(channel 0; its feedback printed as lines: one per candidate or piece change
or 10 %) -> the ExecutePlan action per electrode (``--follow``: followed in
real time with its feedback; by default the result as soon as the trajectory
is sent, so the demo stays fast), with a monitor subscriber receiving the
JointTrajectory; asks the interference_checker for the clearances along
every electrode's whole cycle;
prints a summary and writes ``out/demo/``: the plan export, axis curves
against time and against the sample index (Huang Fig. 7), the clearance per
surface along the path, and the electrode's swept positions in the channel
(GLB and PNG). Every process it started is stopped, also on Ctrl-C or
failure; the exit status is non-zero if any step failed.

The default blisk's file names no electrode design: PlanElectrodeSet
designs the set (its primitive electrode cannot leave the 104-degree
channel), each electrode's whole cycle is executed in turn, and the
removal proof's stock map is copied next to the other pictures. A repeated
run finds the set in the plan store.
"""

import argparse
import os
import pathlib
import signal
import sys

from ...environment import configure_process

# this entry point's set-up, before the core's kernel modules load (numba reads its cache directory then)
configure_process()

from ...quick_exit import exit_now, interrupt_outside_imports
from ...ros.dds import use_loopback_udp
from .bringup import NODES, Bringup


def main(argv=None):
    parser = argparse.ArgumentParser(description="edm_planner end-to-end demo (make demo)")
    parser.add_argument("--out", default="out/demo", help="output directory")
    parser.add_argument("--channel", type=int, default=0)
    parser.add_argument("--follow", action="store_true",
                        help="follow each electrode's trajectory in real time (ExecutePlan feedback; minutes)")
    args = parser.parse_args(argv)
    # Ctrl-C and kill stop the nodes too: raise KeyboardInterrupt here even when the demo was started
    # with SIGINT ignored (a background job of a non-interactive shell inherits SIG_IGN), never inside an
    # import (it would leave the import lock held, and the pictures thread's next import waited for ever)
    interrupt_outside_imports(signal.SIGINT, signal.SIGTERM)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    use_loopback_udp()                      # again: the line above undid what importing edm_planner.nodes did
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 80))
    out = pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    bringup = Bringup(out / "logs", params={"trajectory_planner": {"export_dir": str(out / "plans")}})
    status = 0
    try:
        # the nodes' modules imported in the server process while this one imports rclpy, the messages and
        # the core (about 2 s each)
        bringup.preload()
        from ...ros.runtime import enable_stack_dumps
        from .demo_steps import Step, run
        enable_stack_dumps()
        with Step(f"starting {', '.join(NODES)} (logs in {out / 'logs'})"):
            bringup.start()
        run(out, args.channel, bringup, follow=args.follow)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        status = 130
    except Exception as exc:
        print(f"demo failed: {exc}", file=sys.stderr)
        status = 1
    finally:
        bringup.stop()
        print("all nodes stopped", flush=True)
    return status


if __name__ == "__main__":
    exit_now(main())            # without Python's final teardown of the planner, rclpy and matplotlib (about 1 s)
