"""Vector helpers of the cloth kernels: LLVM IR building blocks for the intrinsics that work on 4 lanes
of <4 x double> (forces, integrate, springs), the cycle counter, and the padded row layout they read.
"""
from __future__ import annotations

import llvmlite.ir as ir
import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from stages.fastmath import V4

@intrinsic
def cycles(typingctx):
    """CPU cycle counter (llvm.readcyclecounter): a nanosecond-scale timer inside njit code."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.readcyclecounter")
        return builder.call(fn, [])

    return sig, codegen


@njit(cache=True)
def read_cycles():
    return cycles()



def shuffle(builder, a, b, lanes):
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(ir.IntType(32), len(lanes)), lanes))


def fmuladd(builder, a, b, c):
    """a b + c, fused where the CPU has FMA (as fastmath contracts the scalar loop)."""
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4] * 3), "llvm.fmuladd.v4f64")
    return builder.call(fn, [a, b, c])


def splat(builder, value):
    """A float64 scalar on 4 lanes."""
    return shuffle(builder, builder.insert_element(ir.Constant(V4, None), value, ir.Constant(ir.IntType(32), 0)),
                    ir.Constant(V4, None), [0, 0, 0, 0])


def transpose(builder, r0, r1, r2, r3):
    """Rows (x, y, z, _) of 4 items -> the x, y, z of the 4 items."""
    xz01 = shuffle(builder, r0, r1, [0, 4, 2, 6])
    y_01 = shuffle(builder, r0, r1, [1, 5, 3, 7])
    xz23 = shuffle(builder, r2, r3, [0, 4, 2, 6])
    y_23 = shuffle(builder, r2, r3, [1, 5, 3, 7])
    return (shuffle(builder, xz01, xz23, [0, 1, 4, 5]), shuffle(builder, y_01, y_23, [0, 1, 4, 5]),
            shuffle(builder, xz01, xz23, [2, 3, 6, 7]))



def padded_rows(n_rows: int) -> np.ndarray:
    """(n + 1, 4) float64 zeros, rows 32-byte aligned (a row across two cache lines costs ~8 %):
    the layout of `correct_springs`' position scratch (row N: the dummy particle of padding springs)
    and of the per-triangle aerodynamic forces (row T: the padding of `vertex_triangles`)."""
    size = 4 * (n_rows + 1)
    buf = np.zeros(size + 4)
    skip = (-buf.ctypes.data % 32) // 8
    return buf[skip:skip + size].reshape(n_rows + 1, 4)
