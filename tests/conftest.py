"""Shared fixtures. Real assets: $GARMENT_ASSETS (default ../shared/assets). When they are absent
the tests that need them skip with the reason, unless GARMENT_REQUIRE_ASSETS=1 (CI) makes that a
failure."""
from __future__ import annotations

import os

import pytest

from pipeline.assets import ASSETS_ENV, assets_dir as _assets_dir

EXPECTED = ("CesiumMan.glb", "RiggedSimple.glb", "cmu_131_01_walk.bvh")


@pytest.fixture(scope="session")
def assets_dir():
    d = _assets_dir()
    missing = [n for n in EXPECTED if not (d / n).is_file()]
    if missing:
        reason = f"real assets missing in {d} ({', '.join(missing)}); set {ASSETS_ENV} to their folder"
        if os.environ.get("GARMENT_REQUIRE_ASSETS") == "1":
            pytest.fail(reason + " [GARMENT_REQUIRE_ASSETS=1]")
        pytest.skip(reason)
    return d
