"""Issue 29: the kernels give the same bits whatever CPU numba compiles them for.

numba compiles for the host CPU unless ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES``
say otherwise, and LLVM vectorises differently for AVX-512, AVX2 and SSE4.2
(the field's stage 1 went from 8 to 4 doubles per instruction and from packed
to scalar integer conversions). The values, the points attaining the minima
and a whole plan must not depend on it: a child process computes them with the
kernels compiled for another CPU (an AVX2 CPU without AVX-512 when this one has
AVX-512, else SSE4.2 only; for the AVX2 one also OpenBLAS's kernels for an AMD
Zen) and they are compared bit for bit with this process's. numba caches each target's code beside the host's, so the child
compiles once per version of the kernel sources.
"""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from cpu_variant_values import values
from edm_planner.bench.cpu import AVX2_TARGET

HERE = pathlib.Path(__file__).resolve().parent

#: SSE4.2 and no AVX (``nehalem``): the variant on a host without AVX-512
SSE42_TARGET = ("nehalem", "+64bit,+sse,+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt,+cmov,+cx8,+cx16,+fxsr,+mmx,"
                           "-avx,-avx2,-fma,-f16c,-avx512f,-avx512dq,-avx512bw,-avx512vl")


def _other_target():
    from edm_planner.bench.cpu import compile_target

    _, features = compile_target()
    return AVX2_TARGET if features.get("avx512f") else SSE42_TARGET


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_kernels_and_plan_are_bit_identical_across_compile_targets(field_cache, tmp_path):
    name, features = _other_target()
    out = tmp_path / f"{name}.npz"
    env = dict(os.environ, NUMBA_CPU_NAME=name, NUMBA_CPU_FEATURES=features, PYTHONPATH=str(HERE))
    if (name, features) == AVX2_TARGET:
        # and OpenBLAS's kernels for an AMD Zen 2 or 3 (what it picks there), not the host's AVX-512 ones: the
        # set-up runs every CPU with AVX2 on the AVX2 kernels, so the plan's BLAS sums must not tell them apart
        env["OPENBLAS_CORETYPE"] = "Zen"
    done = subprocess.run([sys.executable, str(HERE / "cpu_variant_values.py"), str(out), field_cache], env=env,
                          capture_output=True, text=True, timeout=840)
    assert done.returncode == 0, done.stderr[-3000:]
    other = dict(np.load(out))
    here = values(field_cache)
    assert set(other) == set(here)
    for key, value in here.items():
        assert value.dtype == other[key].dtype and value.shape == other[key].shape, key
        # bit for bit (NaN where NaN): not within a tolerance
        as_bytes = [np.ascontiguousarray(np.atleast_1d(v)).view(np.uint8) for v in (value, other[key])]
        assert np.array_equal(*as_bytes), (
            f"{key}: compiled for {name} differs from the host's in "
            f"{int((value != other[key]).sum())} of {value.size} entries")
    assert here["plan_samples"].shape[0] > 100 and np.isfinite(here["pose_min"]).all()
