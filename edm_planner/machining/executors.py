"""Where the set design's tasks run: local spawn worker processes, or Ray (a local Ray or a cluster).

The set designer (:class:`~.electrode_set.SetDesigner`) hands out two kinds of task: the sizing of a
candidate's pieces (each piece's certified-plan attempts, its cycle) and the shares of the wall samples of
the removal proof. Both run in worker processes that hold the geometry, its distance field (loaded from the
field cache) and a designer of their own. :func:`make_executor` gives one interface over

- ``"local"``: a spawn :class:`~concurrent.futures.ProcessPoolExecutor` on this machine (today's workers), and
- ``"ray"``: Ray tasks, on a local Ray started on demand (``address=""`` or ``"local"``) or on an existing
  cluster (``address="host:6379"`` or ``"auto"``, what ``ray start --head`` printed).

Both are :class:`concurrent.futures.Executor` in use: ``submit(fn, *args)`` returns a
:class:`~concurrent.futures.Future`, so the designer and the removal simulation wait on them the same way.
``fn`` is a module-level function; it runs in a worker after ``initializer(*initargs, reports)`` (once per
worker process; with Ray, once per worker process and designer, keyed by a token). ``reports`` is a queue
(``put``/``get_nowait``) the workers' progress records go through to the designer: a multiprocessing queue
locally, a :class:`ray.util.queue.Queue` (an actor, 0 CPU) with Ray.

Ray is imported only when the Ray executor is made (``import ray`` takes about 0.7 s). A local Ray keeps to
the loopback interface (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``: every component binds and advertises
127.0.0.1), runs without its dashboard, keeps its session files, logs and its authentication token in a
temporary directory (not ``~/.ray``) that is removed when the executor shuts down, and starts one CPU slot
per worker. A Ray task that fails because its worker process died (killed, out of memory, its node lost) is
run again, up to ``max_retries`` times (default 3); a task is a pure function of its arguments and of the
worker's initial state, so a retried task returns the same bits.

On a cluster, every node needs this package (the same version, installed in the Python that runs its Ray
workers) and the distance field: a worker loads it from the field cache directory the designer names (the
same path on every node, e.g. a shared file system) and builds it there where it is missing (tens of
seconds, once per node and geometry).

The embedded default (:data:`DEFAULT_KIND`) is ``"local"``, decided by measurement on this 2-core machine
(AMD EPYC family 25 model 1, 2 vCPU at 2.45 GHz, shared with other jobs: load average 4 to 6;
``python -m edm_planner.bench --only scaleout``, three runs on 2026-11-27; docs/performance.md, "Scale-out
with Ray"): the same 6 sizing steps of the default blisk's front/rear pieces, from cold (the executor
started, its workers set up) and again on the warm workers; the plans bit for bit the serial ones in every
run. Seconds, the three runs' values (the third run's warm pass):

| executor | workers | start | first task done | all 6, cold | all 6, warm |
|---|---|---|---|---|---|
| serial, in the caller | (2 threads) | | | 22.4, 13.0, 15.8 | |
| local spawn workers | 1 | 0.01 | 6.3, 5.3, 7.0 | 23.3, 17.9, 19.4 | 11.3 |
| local spawn workers | 2 | 0.00 | 10.8, 10.3, 10.7 | 23.7, 21.2, 16.1 | 4.1 |
| local Ray (on demand) | 1 | 10.8, 7.4, 3.1 | 21.3, 15.3, 8.5 | 32.5, 24.7, 15.8 | 7.3 |
| local Ray (on demand) | 2 | 8.8, 7.3, 4.1 | 22.5, 16.4, 9.9 | 30.5, 24.4, 17.5 | 7.8 |

A local Ray costs a start of its own (the GCS, the raylet, the runtime-env agent: 3 to 11 s) and its first
result comes 2 to 12 s later than a spawn pool's; on one machine it runs the same tasks in as many processes,
so it gains nothing there. The local workers stay the default; Ray pays on a cluster, where more cores than
this machine's 2 take the tasks (``--ray-address``, the node parameter ``ray_address``). The speed-up of 2
workers over 1 on this busy machine is within its noise, cold (0.84 to 1.21) and warm (local 2.76, Ray
0.93): the other jobs take the cores. Figures: :data:`MEASURED`.

Bits: the core's figures depend on the thread count of numpy's BLAS (a sizing step of the rear piece gives
other plan bits with one OpenBLAS thread than with 2); every process runs one
(:func:`~edm_planner.environment.configure_process`), and the Ray tasks are given this process's count
(:func:`blas_threads`) whatever their node's environment, so that they give the bits of the same step run here
and in the local workers.
"""

import concurrent.futures
import logging
import multiprocessing
import os
import pathlib
import pickle
import queue
import secrets
import shutil
import sys
import tempfile
import threading
import time
import weakref

from .set_progress import terminate_pool

_log = logging.getLogger(__name__)

LOCAL, RAY = "local", "ray"
#: the Ray address that asks for a local Ray started on demand (``edm-plan plan --ray-address local``)
LOCAL_RAY = "local"
#: the executor when none is named and no Ray address is given (decided by measurement: see the module's text)
DEFAULT_KIND = LOCAL
#: a task whose worker process died is run again this often (Ray's ``max_retries``)
MAX_RETRIES = 3
#: what the choice of :data:`DEFAULT_KIND` rests on [s] (see the module's text), three runs: kind -> workers ->
#: (start, first task done, all 6 done cold) per run, and the serial runs in the caller
MEASURED = {"cpu": "AMD EPYC family 25 model 1, 2 vCPU, 2.45 GHz, load average 4 to 6 from other jobs",
            "serial_s": (22.4, 13.0, 15.8),
            "local": {1: ((0.01, 6.3, 23.3), (0.01, 5.3, 17.9), (0.01, 7.0, 19.4)),
                      2: ((0.00, 10.8, 23.7), (0.00, 10.3, 21.2), (0.00, 10.7, 16.1))},
            "ray": {1: ((10.8, 21.3, 32.5), (7.4, 15.3, 24.7), (3.1, 8.5, 15.8)),
                    2: ((8.8, 22.5, 30.5), (7.3, 16.4, 24.4), (4.1, 9.9, 17.5))}}

def kind_for(address="", kind=None):
    """The executor kind: ``kind`` when given, Ray when an address is, else :data:`DEFAULT_KIND`."""
    if kind:
        if kind not in (LOCAL, RAY):
            raise ValueError(f"executor kind must be {LOCAL!r} or {RAY!r}, got {kind!r}")
        return kind
    return RAY if address else DEFAULT_KIND


def make_executor(workers, initializer, initargs=(), *, address="", kind=None, reports=False,
                  max_retries=MAX_RETRIES):
    """An executor of ``workers`` worker processes, each set up by ``initializer(*initargs, reports)``.

    Parameters
    ----------
    workers : int
        Worker processes (local, or a local Ray's CPU slots); on a Ray cluster the cluster's CPUs decide.
    initializer : callable
        A module-level function run once in every worker before its first task.
    initargs : tuple
    address : str
        A Ray cluster's address ("host:port" or "auto"), or "local" (a local Ray started on demand); "" : none
        (a local Ray when ``kind`` is "ray").
    kind : str, optional
        "local" or "ray" (default: :func:`kind_for`).
    reports : bool
        Make a queue for the workers' progress records (passed to ``initializer`` last; None without).
    max_retries : int
        Ray only: how often a task whose worker died is run again.
    """
    if kind_for(address, kind) == RAY:
        return RayExecutor(workers, initializer, initargs, address=address, reports=reports,
                           max_retries=max_retries)
    return LocalExecutor(workers, initializer, initargs, reports=reports)


class LocalExecutor:
    """Spawn worker processes on this machine (spawn, not fork: the caller may be a multi-threaded ROS node)."""

    kind = LOCAL

    def __init__(self, workers, initializer, initargs=(), reports=False):
        self.workers = int(workers)
        context = multiprocessing.get_context("spawn")
        self.reports = context.Queue() if reports else None
        # the initializer and its arguments (the geometry: megabytes) reach the workers through a file, not
        # through the pipe a spawned worker starts from: CPython writes a worker's whole start-up data into that
        # pipe while the worker reads it, and a worker that dies before the end (its program has no __main__
        # guard, an import fails, the OOM killer) left the pool blocked in that write for ever. With a few
        # hundred bytes there the write never waits, the pool sees the dead worker and fails its futures
        # (BrokenProcessPool).
        with tempfile.NamedTemporaryFile(prefix="edm_planner_workers_", suffix=".pickle", delete=False) as f:
            pickle.dump((initializer, tuple(initargs)), f, protocol=pickle.HIGHEST_PROTOCOL)
        self.setup_path = f.name
        # removed at shutdown, or at exit at the latest
        self._setup_file = weakref.finalize(self, pathlib.Path(f.name).unlink, missing_ok=True)
        self._pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=self.workers, mp_context=context, initializer=_set_up_from_file,
            initargs=(f.name, self.reports))
        self.where = {}          # nothing to place: one machine

    def submit(self, fn, *args):
        return self._pool.submit(fn, *args)

    def shutdown(self, wait=True, cancel_futures=True):
        self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)
        self._close_reports()
        self._remove_setup_file()

    def terminate(self):
        """Stop at once: the worker processes terminated, waiting futures fail (BrokenProcessPool)."""
        terminate_pool(self._pool)
        self._remove_setup_file()

    def _remove_setup_file(self):
        """The start-up file, once no worker will start any more (the pool shut down or terminated)."""
        self._setup_file()

    def _close_reports(self):
        if self.reports is not None:
            self.reports.close()
            self.reports = None

    def describe(self):
        return f"{self.workers} local worker processes"


def _set_up_from_file(path, reports):
    """A local worker's initializer: ``initializer(*initargs, reports)`` as :class:`LocalExecutor` wrote them."""
    with open(path, "rb") as f:
        initializer, initargs = pickle.load(f)
    initializer(*initargs, reports)


# -- Ray -------------------------------------------------------------------------------------------------

#: in a Ray worker process: the token of the designer whose initializer ran here last
_READY = None


def _edm_task(token, initializer, initargs, fn, args):
    """A Ray task: the worker set up for ``token`` (once), then ``fn(*args)``; (node id, pid, result)."""
    global _READY
    import ray

    if _READY != token:
        initializer(*initargs)
        _READY = token
    return ray.get_runtime_context().get_node_id(), os.getpid(), fn(*args)


def blas_threads():
    """The thread count of this process's OpenBLAS as a string: OPENBLAS_NUM_THREADS (1 after
    ``configure_process``), else OMP_NUM_THREADS, else the CPU count (OpenBLAS's order and default)."""
    return os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS") or str(os.cpu_count() or 1)


def _loopback_environment(temp_dir):
    """The environment of a local Ray on loopback, its token in ``temp_dir``: {name: previous value or None}."""
    token = os.path.join(temp_dir, "auth_token")
    with open(os.open(token, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), "w") as f:
        f.write(secrets.token_hex(32))
    os.makedirs(os.path.join(temp_dir, "ray"), exist_ok=True)
    wanted = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",      # Ray's own switch: every address 127.0.0.1
              "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": token,
              "RAY_TMPDIR": temp_dir,                         # not /tmp/ray (its address file) either
              "RAY_USAGE_STATS_ENABLED": "0"}
    previous = {name: os.environ.get(name) for name in wanted}
    os.environ.update(wanted)
    return previous


def _reread_ray_configuration():
    """Ray was imported before the environment was set: its cached configuration and token read anew."""
    try:
        from ray._raylet import AuthenticationTokenLoader, Config

        Config.initialize("")
        AuthenticationTokenLoader.instance().reset_cache()
    except Exception as exc:        # another Ray version: its start says what is missing
        _log.warning("could not re-read Ray's configuration: %s", exc)


def _restore(previous):
    for name, value in previous.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


#: a local Ray's object store [bytes]: the geometry, the sweeps of a proof (a few MB each), far below this
LOCAL_OBJECT_STORE = 512 * 1024 * 1024
_RAY_LOCK = threading.Lock()


class RayExecutor:
    """Ray tasks: on the cluster at ``address``, on a Ray this process is already connected to, or on a local
    Ray started here (on loopback, in a temporary directory, stopped with :meth:`shutdown`)."""

    kind = RAY

    def __init__(self, workers, initializer, initargs=(), address="", reports=False, max_retries=MAX_RETRIES):
        t0 = time.perf_counter()
        address = "" if address == LOCAL_RAY else address
        self._owned = None              # "local" (started here), "connected" (we connected), None (the caller's)
        self._temp_dir, self._environment = None, {}
        with _RAY_LOCK:
            imported = sys.modules.get("ray")
            start_local = not address and not (imported is not None and imported.is_initialized())
            if start_local:
                # before Ray reads its configuration (at import): loopback, the token in our directory
                self._temp_dir = tempfile.mkdtemp(prefix="edm_ray_")
                self._environment = _loopback_environment(self._temp_dir)
            try:
                import ray              # slow (about 0.7 s): only here
                from ray.util.queue import Queue

                self._ray = ray
                if start_local:
                    if imported is not None:
                        _reread_ray_configuration()
                    ray.init(num_cpus=int(workers), include_dashboard=False, _temp_dir=self._temp_dir,
                             object_store_memory=LOCAL_OBJECT_STORE, log_to_driver=False,
                             logging_level=logging.WARNING)
                    self._owned = "local"
                elif not ray.is_initialized():
                    ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
                    self._owned = "connected"
            except BaseException:
                self._cleanup_local()
                raise
        cpus = int(ray.cluster_resources().get("CPU", 0))
        self.workers = max(1, cpus if (address or self._owned is None) else int(workers))
        self.reports = Queue(actor_options={"num_cpus": 0}) if reports else None
        self._token = secrets.token_hex(8)
        self._initargs = ray.put(tuple(initargs) + (self.reports,))
        self._initializer = initializer
        # the driver's BLAS thread count, whatever a node's environment sets: the core's sums (numpy's BLAS) give
        # other bits with another count, and a task must give the bits of the same step run here; OpenMP's as
        # the driver's too, not Ray's OMP_NUM_THREADS=1
        env_vars = {"OPENBLAS_NUM_THREADS": blas_threads(),
                    "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS") or str(os.cpu_count() or 1)}
        self._remote = ray.remote(num_cpus=1, max_retries=int(max_retries), retry_exceptions=False,
                                  runtime_env={"env_vars": env_vars})(_edm_task)
        self._refs = set()
        self._lock = threading.Lock()
        self.where = {}                 # node id -> tasks finished there
        self.start_s = time.perf_counter() - t0
        _log.info("Ray executor: %s, %d CPUs, ready in %.1f s", self.describe(), self.workers, self.start_s)

    def describe(self):
        if self._owned == "local":
            return f"a local Ray ({self.workers} CPUs)"
        return f"the Ray cluster at {self._ray.get_runtime_context().gcs_address} ({self.workers} CPUs)"

    def submit(self, fn, *args):
        """``fn(*args)`` as a Ray task; a Future of its result, with ``node_id`` and ``pid`` once done."""
        ref = self._remote.remote(self._token, self._initializer, self._initargs, fn, args)
        outer = concurrent.futures.Future()
        outer.set_running_or_notify_cancel()
        with self._lock:
            self._refs.add(ref)

        def done(inner):
            with self._lock:
                self._refs.discard(ref)
            try:
                node_id, pid, result = inner.result()
            except BaseException as exc:            # the task's own error, or Ray's (cancelled, retries used up)
                outer.set_exception(exc)
                return
            outer.node_id, outer.pid = node_id, pid
            with self._lock:
                self.where[node_id] = self.where.get(node_id, 0) + 1
            outer.set_result(result)

        ref.future().add_done_callback(done)
        return outer

    def terminate(self, force=True):
        """Stop at once: every task not finished is cancelled (``force``: its worker killed); waiting futures
        fail."""
        with self._lock:
            refs = list(self._refs)
        for ref in refs:
            try:
                self._ray.cancel(ref, force=force)
            except Exception:                       # already finished
                pass

    def shutdown(self, wait=True, cancel_futures=True):
        """Cancel what is left (``cancel_futures``; running tasks killed unless ``wait``), drop the queue; stop a
        local Ray and remove its files (a cluster's tasks are not left running after a failed design)."""
        if cancel_futures:
            self.terminate(force=not wait)
        if self.reports is not None:
            try:
                self.reports.shutdown(force=True)
            except Exception:
                pass
            self.reports = None
        if self._owned is not None:
            with _RAY_LOCK:
                self._ray.shutdown()
            if self._owned == "local":
                self._cleanup_local()
            self._owned = None

    def _cleanup_local(self):
        _restore(self._environment)
        self._environment = {}
        if self._temp_dir is not None:
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None


def drain(reports):
    """The records waiting in a ``reports`` queue (none without one): a multiprocessing or a Ray queue."""
    out = []
    while reports is not None:
        try:
            out.append(reports.get_nowait())
        except (queue.Empty, OSError, ValueError):
            break
        except Exception:              # a Ray queue whose actor is gone
            break
    return out
