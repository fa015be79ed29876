"""The process set-up every entry point does first: where numba keeps its compiled kernels, how OpenMP waits,
how many threads and which kernels OpenBLAS runs.

Importing :mod:`edm_planner` (or any module of it) changes nothing in the process. The entry points (the
``edm-plan`` command, the nodes, the programs of :mod:`edm_planner.nodes.programs` and :mod:`edm_planner.apps`,
the benchmarks, the test suite's conftest) call :func:`configure_process` before they import the core, because
numba reads its cache directory when a kernel module is imported. A script that uses the core as a library may call it too; without
it numba caches next to the sources (``__pycache__``), keyed by each kernel's own file only. No rclpy.
"""

import hashlib
import logging
import os
import platform
import sys

#: the user's cache: distance fields (keyed by geometry id) and, under ``numba/``, compiled kernels
CACHE_ROOT = os.path.join(os.path.expanduser("~"), ".cache", "edm_planner")
#: where our compiled numba kernels are kept, one subdirectory per version of the kernel sources
NUMBA_CACHE_ROOT = os.path.join(CACHE_ROOT, "numba")
#: OpenBLAS's kernels on every x86-64 CPU with AVX2 and FMA (see :func:`configure_process`)
BLAS_CORETYPE = "Haswell"
#: whether this process's OpenBLAS is set up: loaded after :func:`configure_process` set its variables, or set by
#: it through threadpoolctl (about 70 ms, once: a node's module sets up again after its messages loaded numpy)
_blas_set_up = False
#: the package's source directory, whose kernels :func:`kernel_sources_digest` covers
PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))


#: what a module that defines kernels (compiled code numba caches) contains; a module that only calls numba
#: (``numba.set_num_threads``) or names it in a comment changes no compiled code
KERNEL_MARKERS = (b"njit", b"numba.jit", b"@numba.", b"intrinsic", b"overload", b"cfunc", b"vectorize")


def _sources_digest(package, keep):
    """A digest of the package's modules whose source ``keep(path, text)`` accepts (file name and text; ``path``
    relative to ``package``)."""
    digest = hashlib.sha256()
    for folder, subfolders, files in sorted(os.walk(package)):
        subfolders.sort()
        for name in sorted(f for f in files if f.endswith(".py")):
            path = os.path.join(folder, name)
            with open(path, "rb") as source:
                text = source.read()
            if keep(os.path.relpath(path, package), text):
                digest.update(name.encode() + b"\0" + text)
    return digest.hexdigest()[:16]


def kernel_sources_digest(package=PACKAGE_DIR):
    """A digest of every module of the package that defines numba kernels (about 2 ms).

    numba's cache checks a kernel against its own file's time stamp only, not
    against the files its compiled code was built from (the intrinsics in
    ``interference/cell_simd.py``, kernels of other modules it calls): after
    an edit there, the cached code would be stale. One cache directory per
    content of all kernel sources rules that out. An edit of a module that
    defines no kernel (``KERNEL_MARKERS``) keeps the directory: recompiling
    every kernel costs a new process about a minute.
    """
    # this module names the markers but defines no kernel: its edits keep the directory
    return _sources_digest(package, lambda path, text: path != "environment.py"
                           and any(marker in text for marker in KERNEL_MARKERS))


def package_sources_digest(package=PACKAGE_DIR):
    """A digest of every module of the package (a few ms): what an on-disk cache of computed results is keyed
    by, so that any change of the code computes them anew (``geometry.electrode_cache``)."""
    return _sources_digest(package, lambda path, text: True)


def configure_process(environ=None):
    """Set up this process (and the children it starts) for the core; idempotent.

    * ``NUMBA_CACHE_DIR``: numba keeps the compiled kernels (``cache=True``) in a directory that survives runs
      and is shared by every process (nodes, the CLI, tests), one per version of the kernel sources
      (:func:`kernel_sources_digest`), so each kernel compiles once per machine and source version. A
      ``NUMBA_CACHE_DIR`` given by the caller wins.
    * ``OMP_WAIT_POLICY=PASSIVE`` unless given: numba's parallel kernels run on OpenMP, whose idle threads spin
      by default; with several processes at once (the nodes, the set designer's workers) spinning threads take
      the cores from the ones that work. Read when the OpenMP runtime starts (the first parallel kernel call).
    * ``OPENBLAS_NUM_THREADS=1`` unless given: numpy's and SciPy's OpenBLAS start a thread per core, and their
      sums split over threads add in another order (a plan's bits differed from a 1-core machine's to a 2-core
      one's, by 1e-13 mm); held to one thread, every machine gives the same bits whatever its core count. The
      core's matrices are small (the smoothing basis of a few hundred nodes), so threads do not pay: with the
      set designer's two workers on two cores they waited for each other (the default blisk's set 32-33 s
      with a thread per core, 30 s with one). Read when OpenBLAS loads (numpy's import); a process that
      imported numpy or SciPy before this call is set through threadpoolctl.
    * ``OPENBLAS_CORETYPE=Haswell`` unless given, on an x86-64 CPU with AVX2 and FMA: OpenBLAS picks its
      kernels by CPU when it loads, and its AVX-512 kernels (SkylakeX, on an AMD Zen 4 or a Xeon) sum in
      another order than its AVX2 ones (Haswell, and Zen's, the same code): an AVX-512 machine gave other bits
      than an AVX2 one. Every CPU with AVX2 runs the AVX2 kernels (a CPU without AVX2 keeps its own). Read
      when OpenBLAS loads only: a process that loaded it before this call keeps its kernels (logged).

    Call it before any kernel module is imported; if numba was imported already, its configuration is reloaded.

    Parameters
    ----------
    environ : mutable mapping, optional
        The environment to set (``os.environ``; another mapping is only written, for tests).

    Returns
    -------
    str
        The numba cache directory in use.
    """
    env = os.environ if environ is None else environ
    if "NUMBA_CACHE_DIR" not in env:
        env["NUMBA_CACHE_DIR"] = os.path.join(NUMBA_CACHE_ROOT, kernel_sources_digest())
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    if not env.get("OPENBLAS_CORETYPE") and _has_avx2_and_fma():
        env["OPENBLAS_CORETYPE"] = BLAS_CORETYPE
    global _blas_set_up
    if environ is None and not _blas_set_up:
        _limit_loaded_blas(env["OPENBLAS_NUM_THREADS"], env.get("OPENBLAS_CORETYPE"))
        _blas_set_up = True             # OpenBLAS loads after this call, or was set (and checked) just now
    if environ is None and "numba" in sys.modules:      # imported before: it read its configuration already
        sys.modules["numba"].core.config.reload_config()
    return env["NUMBA_CACHE_DIR"]


def first_cpu_info(cpuinfo="/proc/cpuinfo"):
    """The first processor's fields of ``cpuinfo`` (Linux's /proc/cpuinfo), by name; {} where there is none."""
    info = {}
    try:
        with open(cpuinfo) as f:
            for line in f:
                if not line.strip():            # the first processor's block ends
                    break
                key, _, value = line.partition(":")
                info[key.strip()] = value.strip()
    except OSError:
        pass
    return info


def _has_avx2_and_fma():
    """Whether this is an x86-64 CPU with AVX2 and FMA."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    return {"avx2", "fma"} <= set(first_cpu_info().get("flags", "").split())


def _limit_loaded_blas(threads, coretype):
    """A BLAS loaded before :func:`configure_process` read its variables already: its thread count set now
    (threadpoolctl), and a warning where it runs other kernels than ``coretype``."""
    if not any(name in sys.modules for name in ("numpy", "scipy")):
        return
    from threadpoolctl import threadpool_info, threadpool_limits

    try:
        threadpool_limits(limits=int(threads), user_api="blas")
    except ValueError:
        pass                            # the caller's own setting, which OpenBLAS reads as it does
    other = sorted({lib.get("architecture") for lib in threadpool_info() if lib.get("internal_api") == "openblas"}
                   - {coretype})
    if coretype == BLAS_CORETYPE and other:          # a caller's own choice is theirs to check
        logging.getLogger(__name__).warning(
            "OpenBLAS was loaded before the process set-up and runs its %s kernels, not %s: its sums may differ "
            "from other processes' in the last bits (call configure_process before importing numpy)",
            ", ".join(map(str, other)), coretype)
