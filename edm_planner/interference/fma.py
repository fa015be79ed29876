"""``fma32(a, b, c)``: a * b + c in float32 with a single rounding, for numba kernels.

Python 3.11's ``math`` has no ``fma`` (3.13 adds it) and numba offers none;
this is LLVM's ``llvm.fma.f32`` intrinsic through ``numba.extending.intrinsic``
(one ``vfmadd`` instruction on x86 with FMA3). Always fused, in every
context, unlike ``fastmath={"contract"}``.
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def fma32(typingctx, a, b, c):
    """a * b + c, float32, one rounding."""
    if not all(isinstance(t, types.Float) and t.bitwidth == 32 for t in (a, b, c)):
        return None
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        f32 = ir.FloatType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(f32, [f32, f32, f32]), "llvm.fma.f32")
        return builder.call(fn, args)

    return sig, codegen
