"""The numba warm-up that make setup runs: the whole of it, in its two processes, finishes and says so."""

import os
import subprocess
import sys

import pytest

from conftest import REPO


def test_warm_up_runs_both_parts_and_reports():
    run = subprocess.run([sys.executable, "-m", "edm_planner.apps.warmup"], cwd=REPO, capture_output=True, text=True,
                         timeout=1800)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "warm-up (part 0): numba kernels compiled or loaded from the cache in" in run.stdout
    assert "warm-up (part 1): numba kernels compiled or loaded from the cache in" in run.stdout
    assert "warm-up: done in" in run.stdout


def test_a_bad_part_is_refused_with_a_usage_line():
    run = subprocess.run([sys.executable, "-m", "edm_planner.apps.warmup", "--part", "7"], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "invalid choice" in run.stderr and "Traceback" not in run.stderr


def test_the_kernel_cache_directory_follows_every_kernel_source(tmp_path):
    """numba checks a cached kernel against its own file only; the cache directory is named by all kernel
    sources, so an edit of an intrinsic another file's kernels inline (cell_simd.py) gives a new one, and
    an edit of a module without kernels does not."""
    import os
    import shutil

    from edm_planner.environment import NUMBA_CACHE_ROOT, kernel_sources_digest

    package = tmp_path / "edm_planner"
    shutil.copytree(REPO / "edm_planner", package, ignore=shutil.ignore_patterns("__pycache__"))
    first = kernel_sources_digest(str(package))
    assert first == kernel_sources_digest(str(REPO / "edm_planner"))
    assert os.environ["NUMBA_CACHE_DIR"] == os.path.join(NUMBA_CACHE_ROOT, first)
    (package / "paths.py").write_text((package / "paths.py").read_text() + "\n# no kernel here\n")
    assert kernel_sources_digest(str(package)) == first
    # the module that names the markers (and so holds them) defines no kernel either
    environment = package / "environment.py"
    assert b"njit" in environment.read_bytes()
    environment.write_text(environment.read_text() + "\n# an edit of the process set-up\n")
    assert kernel_sources_digest(str(package)) == first
    # a module that calls numba but compiles nothing (the set designer: numba.set_num_threads)
    designer = package / "machining" / "electrode_set.py"
    assert b"numba.set_num_threads" in designer.read_bytes()
    designer.write_text(designer.read_text() + "\n# an edit of the set designer\n")
    assert kernel_sources_digest(str(package)) == first
    simd = package / "interference" / "cell_simd.py"
    simd.write_text(simd.read_text() + "\n# an edit of the intrinsic\n")
    assert kernel_sources_digest(str(package)) != first


def test_old_kernel_caches_are_pruned_but_not_the_current_one_or_a_recent_one(tmp_path, monkeypatch):
    import os
    import time

    from edm_planner import environment
    from edm_planner.apps.warmup import KEEP_DAYS, prune_kernel_caches

    monkeypatch.setattr(environment, "NUMBA_CACHE_ROOT", str(tmp_path))
    now = time.time()
    for name, age_days in (("current", 400), ("recent", KEEP_DAYS - 1), ("old", KEEP_DAYS + 1)):
        (tmp_path / name / "sub").mkdir(parents=True)
        kernel = tmp_path / name / "sub" / "kernel.nbc"
        kernel.write_bytes(b"x")
        for path in (kernel, kernel.parent, kernel.parent.parent):
            os.utime(path, (now - age_days * 86400,) * 2)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "current"))
    assert prune_kernel_caches(now) == [tmp_path / "old"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["current", "recent"]
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path.parent / "elsewhere"))   # a directory the caller chose
    os.utime(tmp_path / "recent" / "sub" / "kernel.nbc", (0, 0))
    assert prune_kernel_caches(now) == []


def test_importing_the_package_changes_nothing_and_the_set_up_call_does():
    """Importing edm_planner, its domain and its node modules' shared parts leaves the environment alone; the
    entry points' explicit set-up (configure_process) names numba's cache and OpenMP's wait policy."""
    import json

    code = (
        "import json, os, sys\n"
        "before = dict(os.environ)\n"
        "import edm_planner, edm_planner.interference.fast, edm_planner.planning.planner, edm_planner.records.store\n"
        "import edm_planner.ros, edm_planner.nodes, edm_planner.apps\n"
        "changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))\n"
        "from edm_planner.environment import configure_process\n"
        "cache = configure_process()\n"
        "print(json.dumps({'changed': changed, 'cache': cache, 'env': os.environ.get('NUMBA_CACHE_DIR'),\n"
        "                  'omp': os.environ.get('OMP_WAIT_POLICY'), 'blas': os.environ.get('OPENBLAS_NUM_THREADS')}))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "OMP_WAIT_POLICY", "OPENBLAS_NUM_THREADS")}
    run = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["changed"] == []
    from edm_planner.environment import NUMBA_CACHE_ROOT, kernel_sources_digest
    assert out["cache"] == out["env"] == os.path.join(NUMBA_CACHE_ROOT, kernel_sources_digest())
    assert out["omp"] == "PASSIVE"
    assert out["blas"] == "1"


#: a sum OpenBLAS splits over its threads (a dot product of 200 000 terms, numpy's and SciPy's library) as hex,
#: then the libraries' thread counts and kernels; ``{first}`` is what runs before the set-up call
BLAS_SUMS = """
{first}
from edm_planner.environment import configure_process
configure_process()
import numpy as np, scipy.linalg.blas
from threadpoolctl import threadpool_info
rng = np.random.default_rng(7)
a, b = rng.normal(size=200_000), rng.normal(size=200_000)
blas = [lib for lib in threadpool_info() if lib["internal_api"] == "openblas"]
print(float(a @ b).hex(), float(scipy.linalg.blas.ddot(a, b)).hex(),
      ",".join(sorted({{str(lib["num_threads"]) for lib in blas}})),
      ",".join(sorted({{str(lib["architecture"]) for lib in blas}})))
"""


def blas_sums(first="", **environ):
    """BLAS_SUMS in a new process: ([numpy's sum, SciPy's sum, thread counts, kernels], stderr)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_CORETYPE")}
    run = subprocess.run([sys.executable, "-c", BLAS_SUMS.format(first=first)], cwd=REPO, env={**env, **environ},
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout.split(), run.stderr


def test_blas_sums_give_the_same_bits_whatever_the_core_count():
    """numpy's and SciPy's OpenBLAS start a thread per core and split a long sum over them, in another order:
    the set-up holds them to one thread (also where numpy was imported before it: threadpoolctl), so a process
    gives the bits of a one-core machine on any machine, unless the caller sets OPENBLAS_NUM_THREADS."""
    default, _ = blas_sums()
    assert blas_sums(OPENBLAS_NUM_THREADS="1")[0] == default
    assert default[0] == default[1] and default[2] == "1"
    early, _ = blas_sums(first="import numpy, scipy.linalg")
    assert early[2] == "1"
    if (os.cpu_count() or 1) >= 2:        # a machine's default before: a thread per core, other bits
        two, _ = blas_sums(OPENBLAS_NUM_THREADS="2")
        assert two[2] == "2" and two[0] != default[0]


def test_blas_runs_the_avx2_kernels_on_every_avx2_cpu():
    """OpenBLAS picks its kernels by CPU, and its AVX-512 ones (SkylakeX: an AMD Zen 4, a Xeon) sum in another
    order than its AVX2 ones (Haswell, and Zen's, the same code): the set-up makes every CPU with AVX2 run the
    AVX2 kernels, so an AVX-512 machine gives an AVX2 machine's bits. A process that loaded numpy before the
    set-up keeps its kernels, and says so."""
    from edm_planner.environment import BLAS_CORETYPE, _has_avx2_and_fma, first_cpu_info

    if not _has_avx2_and_fma():
        pytest.skip("a CPU without AVX2 and FMA keeps OpenBLAS's own choice")
    default, _ = blas_sums()
    assert default[3] == BLAS_CORETYPE == "Haswell"
    assert blas_sums(OPENBLAS_CORETYPE="Zen")[0][:2] == default[:2]       # an AMD Zen 2 or 3
    if "avx512f" in first_cpu_info().get("flags", "").split():
        own, _ = blas_sums(OPENBLAS_CORETYPE="SkylakeX")                  # what this CPU ran before
        assert own[3] == "SkylakeX" and own[0] != default[0]
        early, stderr = blas_sums(first="import numpy, scipy.linalg")
        assert early[3] == "SkylakeX" and "OpenBLAS was loaded before the process set-up" in stderr
