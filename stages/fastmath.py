"""`inv_sqrt(x)` = 1 / sqrt(x) for numba kernels, from the CPU's reciprocal square-root estimate.

The spring correction (1 - L / |d|) and the aerodynamic force need 1 / sqrt per spring / triangle;
as a sqrt then a divide that costs ~35 cycles of latency per spring in the Gauss-Seidel loop, whose
speed is bound by that latency (benchmark: 3 rounds over the 50 x 50 drape, 170 -> 136 us).
The estimate plus one Newton step (y <- y (1.5 - 0.5 x y^2)) is accurate to INV_SQRT_REL_ERROR:

- x86-64 with AVX-512F and VL (host CPU): vrsqrt14sd, 2^-14 estimate, error after Newton < 1e-8;
- other x86-64: rsqrtss (SSE, float32), 1.5 * 2^-12 estimate, < 3e-7 after Newton; outside the
  float32 normal range the exact form is used;
- other machines: the exact 1.0 / sqrt(x).

The choice follows numba's target CPU (NUMBA_CPU_NAME set = a portable build: no AVX-512).
x must be > 0 and finite; callers skip x <= 0 as they would for the exact form.

`inv_sqrt_v4(builder, x)` emits the same computation on the 4 lanes of an LLVM <4 x double> (for
intrinsics that work on vectors), lane by lane bit-identical to `inv_sqrt`.
"""
from __future__ import annotations

import math
import platform

import llvmlite.ir as ir
from numba import config, njit, types
from numba.core import cgutils
from numba.extending import intrinsic


def _cpu_kind() -> str:
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return "exact"
    if config.CPU_NAME is None:         # compiling for this host
        import llvmlite.binding as ll
        try:
            features = ll.get_host_cpu_features()
            if features.get("avx512f", False) and features.get("avx512vl", False):   # VL: 256-bit form
                return "avx512"
        except RuntimeError:            # features unknown: stay on the x86-64 baseline
            pass
    return "sse"


CPU_KIND = _cpu_kind()
INV_SQRT_REL_ERROR = {"avx512": 1e-8, "sse": 3e-7, "exact": 1e-15}[CPU_KIND]


def _estimate_codegen(name: str, lane: ir.Type, n_args: int):
    """Codegen of a scalar x86 estimate intrinsic on lane 0 of a 128-bit vector."""
    def codegen(context, builder, signature, args):
        vec = ir.VectorType(lane, 128 // (64 if lane == ir.DoubleType() else 32))
        zero = ir.Constant(ir.IntType(32), 0)
        arg = args[0] if lane == ir.DoubleType() else builder.fptrunc(args[0], lane)
        v = builder.insert_element(ir.Constant(vec, None), arg, zero)
        if n_args == 1:
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vec, [vec]), name)
            r = builder.call(fn, [v])
        else:   # avx512 form: (a, b, passthrough, mask) -> estimate of b's lane 0
            fn = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(vec, [vec, vec, vec, ir.IntType(8)]), name)
            r = builder.call(fn, [v, v, ir.Constant(vec, None), ir.Constant(ir.IntType(8), 1)])
        out = builder.extract_element(r, zero)
        return out if lane == ir.DoubleType() else builder.fpext(out, ir.DoubleType())
    return codegen


@intrinsic
def _rsqrt14(typingctx, x):
    return types.float64(types.float64), _estimate_codegen("llvm.x86.avx512.rsqrt14.sd", ir.DoubleType(), 4)


@intrinsic
def _rsqrt_ss(typingctx, x):
    return types.float64(types.float64), _estimate_codegen("llvm.x86.sse.rsqrt.ss", ir.FloatType(), 1)


@njit(cache=True, inline="always")
def inv_sqrt_avx512(x):
    """1 / sqrt(x) from vrsqrt14sd + one Newton step (AVX-512F only); relative error < 1e-8."""
    y = _rsqrt14(x)
    return y * (1.5 - 0.5 * x * y * y)


@njit(cache=True, inline="always")
def inv_sqrt_sse(x):
    """1 / sqrt(x) from rsqrtss + one Newton step (any x86-64); relative error < 3e-7."""
    if x < 1e-36 or x > 1e36:      # outside float32's normal range
        return 1.0 / math.sqrt(x)
    y = _rsqrt_ss(x)
    return y * (1.5 - 0.5 * x * y * y)


@njit(cache=True, inline="always")
def inv_sqrt_exact(x):
    return 1.0 / math.sqrt(x)


inv_sqrt = {"avx512": inv_sqrt_avx512, "sse": inv_sqrt_sse, "exact": inv_sqrt_exact}[CPU_KIND]


# -- 4 lanes at once: LLVM IR for intrinsics (<4 x double> in, <4 x double> out) --------------------
V4 = ir.VectorType(ir.DoubleType(), 4)


def v4_const(value: float) -> ir.Constant:
    """The constant `value` on the 4 lanes of a V4."""
    return ir.Constant(V4, [value] * 4)


def _newton_v4(builder, x, y):
    """y (1.5 - 0.5 x y y), the scalar variants' Newton step in their operation order."""
    return builder.fmul(y, builder.fsub(v4_const(1.5), builder.fmul(builder.fmul(builder.fmul(v4_const(0.5), x), y), y)))


def _exact_v4(builder, x):
    sqrt = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4]), "llvm.sqrt.v4f64")
    return builder.fdiv(v4_const(1.0), builder.call(sqrt, [x]))


def inv_sqrt_v4_avx512(builder, x):
    """IR: inv_sqrt_avx512 on 4 lanes (vrsqrt14pd ymm, AVX-512F + VL)."""
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4, V4, ir.IntType(8)]),
                                        "llvm.x86.avx512.rsqrt14.pd.256")
    y = builder.call(fn, [x, ir.Constant(V4, None), ir.Constant(ir.IntType(8), -1)])
    return _newton_v4(builder, x, y)


def inv_sqrt_v4_sse(builder, x):
    """IR: inv_sqrt_sse on 4 lanes (rsqrtps); lanes outside float32's normal range take the exact
    form, computed only when there is one (a branch, not a select)."""
    v4f = ir.VectorType(ir.FloatType(), 4)
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(v4f, [v4f]), "llvm.x86.sse.rsqrt.ps")
    y = builder.fpext(builder.call(fn, [builder.fptrunc(x, v4f)]), V4)
    estimated = _newton_v4(builder, x, y)
    outside = builder.or_(builder.fcmp_ordered("<", x, v4_const(1e-36)), builder.fcmp_ordered(">", x, v4_const(1e36)))
    any_outside = builder.icmp_unsigned("!=", builder.bitcast(outside, ir.IntType(4)), ir.Constant(ir.IntType(4), 0))
    start = builder.block
    with builder.if_then(any_outside, likely=False):
        mixed = builder.select(outside, _exact_v4(builder, x), estimated)
        outside_block = builder.block
    out = builder.phi(V4)
    out.add_incoming(estimated, start)
    out.add_incoming(mixed, outside_block)
    return out


def inv_sqrt_v4_exact(builder, x):
    """IR: 1 / sqrt on 4 lanes."""
    return _exact_v4(builder, x)


inv_sqrt_v4 = {"avx512": inv_sqrt_v4_avx512, "sse": inv_sqrt_v4_sse, "exact": inv_sqrt_v4_exact}[CPU_KIND]
