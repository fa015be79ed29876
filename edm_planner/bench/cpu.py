"""What a benchmark ran on (issue 29): every figure names its CPU.

``cpu_record()`` reads ``/proc/cpuinfo`` (model name, vendor, family, model,
stepping, the clock the kernel reports) and the cpufreq limits where they are
readable, and asks numba and LLVM what the kernels were compiled for: the CPU
name and the SIMD features (``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` when
set, else the host's), so that a figure measured with the kernels compiled
for an older CPU (``emulated_target``) says so.
"""

import os
import pathlib
import platform

import numba
from numba.core import config
from numba.core.registry import cpu_target

from ..environment import first_cpu_info

#: the SIMD features that decide how the kernels vectorise, in the order reported
SIMD_FEATURES = ("sse4.2", "avx", "avx2", "fma", "avx512f", "avx512dq", "avx512bw", "avx512vl")

#: the AVX2 CPU of issue 29 (AMD Zen 3) for numba: ``NUMBA_CPU_NAME``, ``NUMBA_CPU_FEATURES`` (without
#: the features numba would otherwise take from the host, AVX-512 among them)
AVX2_TARGET = ("znver3", "+64bit,+sse,+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt,+cmov,+cx8,+cx16,+fxsr,+mmx,"
                         "+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+movbe,+xsave,-avx512f,-avx512dq,-avx512bw,"
                         "-avx512vl,-avx512cd,-avx512vnni,-avx512bf16,-avx512fp16,-amx-tile")


def _khz(name):
    try:
        return int(pathlib.Path(f"/sys/devices/system/cpu/cpu0/cpufreq/{name}").read_text())
    except (OSError, ValueError):
        return None


def compile_target():
    """(cpu name, {feature: bool}) numba's kernels are compiled for in this process.

    Numba's own answer: the CPU and features its code generator targets and keys its cache by
    (``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` where set, else the host's, less AVX where numba disables it).
    """

    _, name, features = cpu_target.target_context.codegen().magic_tuple()
    return name, {f[1:]: f[0] == "+" for f in features.split(",") if f}


def cpu_record():
    """The CPU and the kernels' compile target, for a benchmark's JSON."""

    info = first_cpu_info()
    flags = set(info.get("flags", "").split())
    name, features = compile_target()
    max_khz, cur_khz = _khz("cpuinfo_max_freq"), _khz("scaling_cur_freq")
    return {
        "model_name": info.get("model name", platform.processor() or platform.machine()),
        "vendor": info.get("vendor_id"),
        "family": int(info["cpu family"]) if "cpu family" in info else None,
        "model": int(info["model"]) if "model" in info else None,
        "stepping": int(info["stepping"]) if info.get("stepping", "").isdigit() else None,
        "cpu_mhz_reported": float(info["cpu MHz"]) if "cpu MHz" in info else None,
        "max_mhz": max_khz / 1000 if max_khz else None,
        "current_mhz": cur_khz / 1000 if cur_khz else None,
        "logical_cpus": os.cpu_count(),
        "numba_threads": numba.get_num_threads(),
        "cpu_simd": [f for f in SIMD_FEATURES if f.replace(".", "_") in flags],
        "kernels_compiled_for": name,
        "kernels_simd": [f for f in SIMD_FEATURES if features.get(f)],
        "emulated_target": config.CPU_NAME is not None,
    }


def cpu_label(record):
    """A short name for tables: model name, family/model, and the target when emulated."""
    label = f"{record['model_name']} (family {record['family']}, model {record['model']})"
    if record["emulated_target"]:
        label += f", kernels compiled for {record['kernels_compiled_for']} ({'/'.join(record['kernels_simd'])})"
    return label
