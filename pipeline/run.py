"""Stage orchestration: scene settings -> stage inputs, stages in data-flow order, logging, summary.

Stage order: rig (character, motion, skinning, region split) -> hulls (colliders) -> maps ->
garments -> simulation (with obstacles). Each stage's wall time and output sizes go into the
end summary and the recording's `meta/summary`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.scene import Scene
from pipeline.schema import SceneError


@dataclass
class StageReport:
    name: str
    seconds: float
    sizes: dict = field(default_factory=dict)


@dataclass
class RunSummary:
    scene: str
    output: Path | None
    frames: int
    stages: list[StageReport] = field(default_factory=list)
    penetrations: dict = field(default_factory=dict)
    tables: dict = field(default_factory=dict)   # name -> markdown table (fit report, map stats)

    def text(self) -> str:
        lines = [f"scene {self.scene}: {self.frames} frames"]
        for s in self.stages:
            sizes = ", ".join(f"{k} {v}" for k, v in s.sizes.items())
            lines.append(f"  {s.name:<10} {s.seconds * 1000:9.1f} ms   {sizes}")
        for k, v in self.penetrations.items():
            lines.append(f"  {k}: {v}")
        if self.output:
            lines.append(f"recording: {self.output}  (view: rerun {self.output})")
        return "\n".join(lines)

    def markdown(self) -> str:
        out = [f"# {self.scene}", "", f"{self.frames} frames", "", "| stage | time (ms) | sizes |", "| --- | ---: | --- |"]
        for s in self.stages:
            out.append(f"| {s.name} | {s.seconds * 1000:.1f} | " + ", ".join(f"{k} {v}" for k, v in s.sizes.items()) + " |")
        if self.penetrations:
            out += ["", "## Penetrations", ""] + [f"- {k}: {v}" for k, v in self.penetrations.items()]
        for name, table in self.tables.items():
            out += ["", f"## {name}", "", table]
        return "\n".join(out)


class _Timer:
    def __init__(self, summary: RunSummary, name: str):
        self.summary, self.name = summary, name

    def __enter__(self):
        self.t0 = time.perf_counter()
        self.report = StageReport(self.name, 0.0)
        return self.report

    def __exit__(self, *exc):
        self.report.seconds = time.perf_counter() - self.t0
        if exc[0] is None:
            self.summary.stages.append(self.report)
        return False


def body_params(settings: dict):
    from stages.rig.procedural import BodyParams
    b = settings["character"]["body"]
    return BodyParams(height=b["height"], chest=b["chest"], waist=b["waist"], hips=b["hips"],
                      arms=b["arms"], legs=b["legs"])


def load_character(scene: Scene):
    """The scene's character from its source (built-in generator, glTF or BVH)."""
    c = scene["character"]
    if c["source"] == "procedural":
        from stages.rig.procedural import procedural_character
        return procedural_character(body_params(scene.settings))
    path = Path(c["path"])
    if not path.is_file():
        raise SceneError(f"{scene.path or '<scene>'}: character.path: file not found: {path}")
    if c["source"] == "gltf":
        from stages.rig.gltf import load_gltf
        return load_gltf(path, scale=c["scale"], up_axis=c["up_axis"])
    from stages.rig.bvh import load_bvh_character
    return load_bvh_character(path, scale=c["scale"], body=body_params(scene.settings))


def frame_times(scene: Scene, frames: int | None = None) -> np.ndarray:
    """Clip times of the frames to run: start + k * dt."""
    n = frames if frames is not None else scene["frames"]["count"]
    return scene["frames"]["start"] + scene["simulation"]["dt"] * np.arange(n, dtype=np.float64)


def check_references(scene: Scene, character) -> None:
    """Names the scene uses that only the character can confirm (clip, joints)."""
    src = scene.path or "<scene>"
    clip = scene["character"]["clip"]
    if not (clip == "rest" or isinstance(clip, (int, str)) and not isinstance(clip, bool)):
        raise SceneError(f"{src}: character.clip: expected a clip name, an index or 'rest', got {clip!r}")
    if clip != "rest":
        try:
            character.clip(clip)
        except KeyError:
            raise SceneError(f"{src}: character.clip: {clip!r} is not a clip of {character.name!r}; "
                             f"clips: {[c.name for c in character.clips] or 'none'} (or 'rest')") from None
    names = set(character.joint_names)
    for i, g in enumerate(scene["garments"]):
        refs = [("at_joint", g.get("at_joint"))]
        if g["pin"] is not None:
            refs.append(("pin.collider", g["pin"]["collider"]))
        for key, name in refs:
            if name is not None and name not in names:
                import difflib
                near = difflib.get_close_matches(name, sorted(names), n=1)
                hint = f" (did you mean {near[0]!r}?)" if near else f"; joints: {', '.join(character.joint_names)}"
                raise SceneError(f"{src}: garments[{i}].{key}: {name!r} is not a joint of {character.name!r}{hint}")


def sample_scene_motion(scene: Scene, character, times: np.ndarray):
    from stages.rig.skinning import rest_motion, sample_motion
    clip = scene["character"]["clip"]
    if clip == "rest" or not character.clips:
        return rest_motion(character, len(times), scene["simulation"]["dt"])
    return sample_motion(character, clip, times)
