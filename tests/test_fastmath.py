"""stages.fastmath.inv_sqrt against numpy's exact 1 / sqrt."""
import numpy as np
import pytest
from numba import njit

import stages.fastmath as F

_BOUND = {"inv_sqrt_avx512": 1e-8, "inv_sqrt_sse": 3e-7, "inv_sqrt_exact": 1e-15}
_RUNS_HERE = {"inv_sqrt_avx512": F.CPU_KIND == "avx512", "inv_sqrt_sse": F.CPU_KIND in ("avx512", "sse"),
              "inv_sqrt_exact": True}


def _values():
    rng = np.random.default_rng(0)
    return np.concatenate([10.0 ** rng.uniform(-60, 60, 200_000), rng.uniform(0.5, 2.0, 200_000),
                           [1e-300, 1e300, 1.0, 4.0, 2.0 ** -20]])


@pytest.mark.parametrize("name", sorted(_BOUND))
def test_inv_sqrt_variants_within_their_bound(name):
    if not _RUNS_HERE[name]:
        pytest.skip(f"{name} needs a CPU this machine does not have ({F.CPU_KIND})")
    g = getattr(F, name)

    @njit   # not cached: it inlines the function under test
    def run(a, out):
        for i in range(a.size):
            out[i] = g(a[i])

    a = _values()
    out = np.empty_like(a)
    run(a, out)
    err = np.abs(out * np.sqrt(a) - 1.0)
    assert err.max() < _BOUND[name]


def test_selected_variant_and_documented_bound_agree():
    assert F.inv_sqrt is getattr(F, f"inv_sqrt_{F.CPU_KIND}")
    assert F.INV_SQRT_REL_ERROR == _BOUND[f"inv_sqrt_{F.CPU_KIND}"]


def _lanes_kernel(emit):
    """njit (not cached) kernel out[4 k: 4 k + 4] = emit(a[4 k: 4 k + 4]) through an intrinsic."""
    import llvmlite.ir as ir
    from numba import types
    from numba.extending import intrinsic

    @intrinsic
    def on_lanes(typingctx, a, out, k):
        def codegen(context, builder, signature, args):
            ptrs = [builder.bitcast(builder.gep(context.make_array(ty)(context, builder, arr).data,
                                               [builder.mul(args[2], ir.Constant(args[2].type, 4))]),
                                    F.V4.as_pointer()) for ty, arr in zip(signature.args[:2], args[:2])]
            builder.store(emit(builder, builder.load(ptrs[0], align=8)), ptrs[1], align=8)
            return context.get_dummy_value()
        return types.void(a, out, k), codegen

    @njit
    def run(a, out):
        for k in range(a.size // 4):
            on_lanes(a, out, k)
    return run


@pytest.mark.parametrize("name", sorted(_BOUND))
def test_inv_sqrt_v4_variants_equal_scalar_lane_by_lane(name):
    """The 4-lane IR of each variant gives the scalar variant's bits on every lane (both in one
    kind of kernel: plain IEEE here), including float32-range fallbacks mixed with estimates."""
    if not _RUNS_HERE[name]:
        pytest.skip(f"{name} needs a CPU this machine does not have ({F.CPU_KIND})")
    g = getattr(F, name)

    @njit
    def scalar(a, out):
        for i in range(a.size):
            out[i] = g(a[i])

    a = np.concatenate([_values(), [1e-300, 1.0, 1e300]])     # a multiple of 4 lanes
    assert a.size % 4 == 0
    want = np.empty_like(a)
    got = np.empty_like(a)
    scalar(a, want)
    _lanes_kernel(getattr(F, name.replace("inv_sqrt", "inv_sqrt_v4")))(a, got)
    np.testing.assert_array_equal(got, want)


def test_selected_v4_variant_matches_scalar_choice():
    assert F.inv_sqrt_v4 is getattr(F, f"inv_sqrt_v4_{F.CPU_KIND}")
