"""What a test that misses its deadline shows: the stacks of the child processes it started.

pytest-timeout fails a test at its deadline (``timeout`` in setup.cfg) and
prints every thread of the test process; a hang is as often in a child (a
node stuck in DDS, a demo waiting on one). Children are registered here
when started; shortly before the deadline :func:`report_children` prints,
for each live one, its Python and native stacks (``py-spy dump``), or, when
py-spy cannot attach, asks it for its Python stacks (``SIGUSR1``:
faulthandler, which our entry points enable) and prints the end of its log.
"""

import os
import pathlib
import shutil
import signal
import subprocess
import sys
import threading
import time

_lock = threading.Lock()
#: pid -> (name, Popen, log path or None) of the children started by the current test process
CHILDREN = {}


def register(proc, name, log=None):
    """Remember a child process (a ``subprocess.Popen``) for the hang report; returns ``proc``."""
    with _lock:
        CHILDREN[proc.pid] = (name, proc, pathlib.Path(log) if log else None)
    return proc


def _py_spy(pid, timeout=30.0):
    exe = shutil.which("py-spy") or os.path.join(sys.prefix, "bin", "py-spy")
    if not os.path.exists(exe):
        return None
    try:
        run = subprocess.run([exe, "dump", "--native", "--pid", str(pid)], capture_output=True, text=True,
                             timeout=timeout)
    except subprocess.TimeoutExpired:
        return None
    return run.stdout if run.returncode == 0 and run.stdout.strip() else None


def report_children(out=None):
    """Print the stacks of every registered child still running (and forget the ones that ended)."""
    out = out or sys.stderr
    with _lock:
        live = [(pid, v) for pid, v in CHILDREN.items() if v[1].poll() is None]
        for pid in [pid for pid, v in CHILDREN.items() if v[1].poll() is not None]:
            del CHILDREN[pid]
    for pid, (name, proc, log) in live:
        print(f"\n===== deadline near: child {name} (pid {pid}) still running =====", file=out)
        stacks = _py_spy(pid)
        if stacks is not None:
            print(stacks, file=out)
            continue
        try:
            os.kill(pid, signal.SIGUSR1)           # faulthandler: the Python stacks into its log
        except ProcessLookupError:
            continue
        time.sleep(1.0)
        if log is not None and log.exists():
            print(log.read_text(errors="replace")[-8000:], file=out)
        else:
            print("(py-spy could not attach; the child's stderr has its Python stacks)", file=out)
    out.flush()


def pipe_holders(stream):
    """(pid, command line) of every process with the pipe of ``stream`` (a file object, our end) open.

    A caller reading a child's output to its end waits for the last of them: the child, or anything that inherited
    the pipe from it and still runs.
    """
    want = os.readlink(f"/proc/self/fd/{stream.fileno()}")          # pipe:[inode]
    holders = []
    for entry in pathlib.Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if any(os.readlink(fd) == want for fd in (entry / "fd").iterdir()):
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
                holders.append((int(entry.name), cmd))
        except OSError:                                             # ended meanwhile, or not ours to read
            continue
    return holders


def holders_report(stream):
    """The processes holding ``stream``'s pipe, each with its Python stacks (py-spy), as text for a failure."""
    lines = []
    for pid, cmd in pipe_holders(stream):
        lines.append(f"--- pid {pid} holds the pipe: {cmd[:300]}")
        lines.append(_py_spy(pid) or "(py-spy could not attach)")
    return "\n".join(lines) or "no process holds the pipe any more"


def forget_all():
    with _lock:
        CHILDREN.clear()
