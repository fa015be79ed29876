"""``python -m edm_planner.bench``: run the benchmark suites, write and print JSON."""

import argparse
import json
import logging
import os
import pathlib
import platform
import resource
import sys
import time
import traceback

from ..environment import configure_process

# this entry point's set-up, before the suites import the core's kernel modules (numba's cache directory)
configure_process()

from .suites import OPT_IN, SUITES  # noqa: E402  (after the set-up above)
from .cpu import AVX2_TARGET, cpu_label, cpu_record  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description="Run the edm_planner benchmarks (JSON out).")
    parser.add_argument("--out", default="out/bench.json", help="JSON file to write")
    parser.add_argument("--only", choices=sorted(SUITES), action="append",
                        help=f"run only these suites (default: all but {', '.join(sorted(OPT_IN))}, run only when named)")
    parser.add_argument("--emulate-avx2", action="store_true",
                        help="compile the kernels for an AVX2 CPU without AVX-512 (AMD Zen 3: NUMBA_CPU_NAME, "
                             "NUMBA_CPU_FEATURES), in this process and the ones it starts; the arithmetic of "
                             "that CPU, not its caches, memory or clock")
    args = parser.parse_args(argv)
    if args.emulate_avx2 and os.environ.get("NUMBA_CPU_NAME") != AVX2_TARGET[0]:
        # numba reads its target when it is imported: start again with it set (every child inherits it)
        env = dict(os.environ, NUMBA_CPU_NAME=AVX2_TARGET[0], NUMBA_CPU_FEATURES=AVX2_TARGET[1])
        os.execve(sys.executable, [sys.executable, "-m", "edm_planner.bench"] + list(sys.argv[1:] if argv is None
                                                                                    else argv), env)
    logging.basicConfig(level=logging.WARNING)
    cpu = cpu_record()
    logging.getLogger(__name__).warning("bench on %s", cpu_label(cpu))
    result = {"machine": {"python": platform.python_version(), "processor": platform.machine(), "cpu": cpu},
              "timestamp": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    failed = []
    for name in args.only or sorted(set(SUITES) - OPT_IN):
        t = time.perf_counter()
        try:
            result[name] = SUITES[name]()
        except Exception as e:           # one suite's failure loses neither the others' figures nor its cause
            logging.getLogger(__name__).exception("suite %s failed", name)
            result[name] = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()}
            failed.append(name)
        result[name]["suite_s"] = round(time.perf_counter() - t, 2)
    result["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    path = pathlib.Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
    logging.getLogger(__name__).warning("wrote %s:\n%s", path, json.dumps(result, indent=2))
    if failed:
        logging.getLogger(__name__).error("failed suites (their errors are in %s): %s", path, ", ".join(failed))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
