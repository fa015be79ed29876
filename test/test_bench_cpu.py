"""Issue 29: a benchmark names the CPU it ran on and the target numba compiled the kernels for."""

import json
import os
import subprocess
import sys

from edm_planner.bench.cpu import AVX2_TARGET, SIMD_FEATURES, cpu_label, cpu_record


def test_the_record_names_this_cpu_and_the_host_target():
    r = cpu_record()
    with open("/proc/cpuinfo") as f:
        first = f.read().split("\n\n")[0]
    assert f"model name\t: {r['model_name']}" in first
    assert f"cpu family\t: {r['family']}" in first and f"model\t\t: {r['model']}" in first
    assert r["logical_cpus"] == os.cpu_count() and r["numba_threads"] >= 1
    assert set(r["cpu_simd"]) <= set(SIMD_FEATURES) and "sse4.2" in r["cpu_simd"]
    # not emulated: the kernels are compiled for the host, with the SIMD it has
    assert not r["emulated_target"] and r["kernels_compiled_for"]
    assert set(r["kernels_simd"]) == set(r["cpu_simd"])
    assert str(r["family"]) in cpu_label(r) and "compiled for" not in cpu_label(r)


def test_an_emulated_target_is_recorded_as_such():
    env = dict(os.environ, NUMBA_CPU_NAME=AVX2_TARGET[0], NUMBA_CPU_FEATURES=AVX2_TARGET[1])
    code = "import json; from edm_planner.bench.cpu import cpu_record; print(json.dumps(cpu_record()))"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    r = json.loads(done.stdout.strip().splitlines()[-1])
    assert r["emulated_target"] and r["kernels_compiled_for"] == "znver3"
    assert "avx2" in r["kernels_simd"] and "fma" in r["kernels_simd"]
    assert not any(f.startswith("avx512") for f in r["kernels_simd"])
    assert "kernels compiled for znver3" in cpu_label(r)
