"""``prefetch(array, index)``: ask the CPU to bring ``array[index]`` into its caches, for numba kernels.

numba has no prefetch, and no library gives one to numba code; this is LLVM's
``llvm.prefetch`` intrinsic (read, high locality, data cache: ``prefetcht0``
on x86) through ``numba.extending.intrinsic``, written by hand for that
reason. A prefetch never faults and changes no value: only when the line
arrives. The pose kernels use it to fetch the grid cells of the points a few
iterations ahead of their loads (``field_query._block_values``).
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def prefetch(typingctx, array, index):
    """Prefetch ``array[index]`` (a C-contiguous array, an integer flat index) for reading."""
    if not isinstance(array, types.Array) or not isinstance(index, types.Integer):
        return None
    sig = types.void(array, index)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        byte_ptr = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [byte_ptr, i32, i32, i32]),
                                            "llvm.prefetch.p0i8")
        # (address, read = 0, locality = 3: keep in all levels, cache type = 1: data)
        builder.call(fn, [builder.bitcast(builder.gep(data, [args[1]]), byte_ptr), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return sig, codegen
