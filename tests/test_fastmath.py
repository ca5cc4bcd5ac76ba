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
