"""``cell_values``: the fast field's float32 cell interpolation in 4-wide SIMD, for numba kernels.

One query point reads one blade-grid cell (four (x, r) corners, each 4
contiguous floats: suction and pressure at theta and theta + 1) and one
hub/shroud-table cell (two x corners, each hub and shroud at r and r + 1).
The interpolation is lerps ``lo + w * (hi - lo)``: over theta, then over r
(blade and walls), then over x. Written as <4 x float> vectors it is 6
vector loads and 5 vector lerps instead of 24 scalar loads and 20 scalar
lerps; LLVM's SLP vectoriser does not find this (no consecutive stores to
seed it), and numba has no SIMD types, so it is LLVM IR written by hand
through ``numba.extending.intrinsic``.

Every lane does the scalar code's operations in the same order, in IEEE
float32 with no fused multiply-add (no fast-math flags): the values are bit
for bit those of the scalar formula (``test_fast_field`` checks it against a
numpy float32 reference). Only 128-bit vectors and in-lane shuffles: an 8-wide
variant with cross-lane shuffles measured twice as slow on this machine
(AMD Zen 5).
"""

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

_LO, _HI = [0, 1, 4, 5], [2, 3, 6, 7]


def _float32_array(t):
    return isinstance(t, types.Array) and t.dtype == types.float32 and t.layout == "C"


@intrinsic
def cell_values(typingctx, flat, b0, sr, sx, wx, wr, wt, hs, c0, hsr, ax, ar):
    """(suction, pressure, hub, shroud) as float32, interpolated in one blade cell and one wall cell.

    ``flat``: the blade grid, (x, r, theta, wall) flattened; ``b0`` the flat
    index of the cell's lower corner, ``sr``/``sx`` the strides of r and x.
    ``hs``: the hub/shroud table, (x, r, wall) flattened; ``c0`` the cell's
    flat index, ``hsr`` the stride of x. ``wx, wr, wt`` and ``ax, ar``: the
    float32 weights in the cells. Indices unsigned 64-bit (no wrap-around).
    """
    if not (_float32_array(flat) and _float32_array(hs)
            and all(t == types.uint64 for t in (b0, sr, sx, c0, hsr))
            and all(t == types.float32 for t in (wx, wr, wt, ax, ar))):
        return None
    sig = types.UniTuple(types.float32, 4)(flat, b0, sr, sx, wx, wr, wt, hs, c0, hsr, ax, ar)

    def codegen(context, builder, signature, args):
        flat, b0, sr, sx, wx, wr, wt, hs, c0, hsr, ax, ar = args
        blade = context.make_array(signature.args[0])(context, builder, flat).data
        walls = context.make_array(signature.args[7])(context, builder, hs).data
        f32, i32 = ir.FloatType(), ir.IntType(32)
        vec4 = ir.VectorType(f32, 4)

        def load4(data, index):                # 4 contiguous floats; the cells are 8-byte aligned only
            return builder.load(builder.bitcast(builder.gep(data, [index]), vec4.as_pointer()), align=4)

        def pick(a, b, lanes):                 # lanes of a (0-3) and b (4-7)
            return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(i32, 4), lanes))

        def weights(*w):
            v = ir.Constant(vec4, ir.Undefined)
            for k, x in enumerate(w):
                v = builder.insert_element(v, x, i32(k))
            return v

        def lerp(a, b, w):
            """[a0 a1 b0 b1] + w * ([a2 a3 b2 b3] - [a0 a1 b0 b1]): each lane as the scalar code's lerp."""
            lo, hi = pick(a, b, _LO), pick(a, b, _HI)
            return builder.fadd(lo, builder.fmul(w, builder.fsub(hi, lo)))

        x1 = builder.add(b0, sx)
        # corners (x, r) = 00, 01, 10, 11, each [s p] at theta and at theta + 1
        c00, c01 = load4(blade, b0), load4(blade, builder.add(b0, sr))
        c10, c11 = load4(blade, x1), load4(blade, builder.add(x1, sr))
        w_t = weights(wt, wt, wt, wt)
        t0 = lerp(c00, c01, w_t)                                     # over theta: [s00 p00 s01 p01]
        t1 = lerp(c10, c11, w_t)                                     # [s10 p10 s11 p11]
        blade_r = lerp(t0, t1, weights(wr, wr, wr, wr))              # over r: [s0 p0 s1 p1]
        # the walls' corners x, x + 1, each [hub shroud] at r and at r + 1; over r: [h0 k0 h1 k1]
        walls_r = lerp(load4(walls, c0), load4(walls, builder.add(c0, hsr)), weights(ar, ar, ar, ar))
        out = lerp(blade_r, walls_r, weights(wx, wx, ax, ax))        # over x: [s p h k]
        return context.make_tuple(builder, signature.return_type,
                                  [builder.extract_element(out, i32(k)) for k in range(4)])

    return sig, codegen
