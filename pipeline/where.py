"""What the command is doing now (stage, scene file, item), for the CLI's last-resort error line.

The orchestration (pipeline/run.py, pipeline/cli.py) sets it; stages never touch it. An unexpected
exception is reported as "internal error in stage S of SCENE (while ITEM)" instead of a traceback.
"""
from __future__ import annotations

import contextlib

_now = {"stage": "start", "scene": None, "item": None}


def reset(scene=None) -> None:
    _now.update(stage="loading the scene", scene=None if scene is None else str(scene), item=None)


def stage(name: str) -> None:
    """Enter a stage; the item is cleared."""
    _now.update(stage=name, item=None)


def set_item(description: str | None) -> None:
    _now["item"] = description


@contextlib.contextmanager
def item(description: str):
    """The item being processed inside the block (a garment, an obstacle, the character file)."""
    before = _now["item"]
    _now["item"] = description
    yield   # on an exception the item stays set: the last-resort handler reports what failed
    _now["item"] = before


def current() -> dict:
    return dict(_now)
