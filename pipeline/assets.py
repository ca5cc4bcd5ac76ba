"""Where the real third-party assets live: $GARMENT_ASSETS, default ../shared/assets beside the repo."""
from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
ASSETS_ENV = "GARMENT_ASSETS"


def assets_dir() -> Path:
    env = os.environ.get(ASSETS_ENV)
    return Path(env).expanduser() if env else REPO_ROOT.parent / "shared" / "assets"
