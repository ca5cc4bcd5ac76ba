"""The end-of-run summary: each stage's wall time and output sizes, the penetrations, the tables;
printed at the end of a run and written into the recording's `meta/summary`."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path


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
    timings: dict = field(default_factory=dict)  # wall-clock seconds besides the stages' (sewing)
    speeds: dict = field(default_factory=dict)   # wall-clock rates, formatted (simulation steps/s)
    exports: list = field(default_factory=list)  # files written by output.export (pipeline.export)

    def text(self) -> str:
        lines = [f"scene {self.scene}: {self.frames} frames"]
        for s in self.stages:
            sizes = ", ".join(f"{k} {v}" for k, v in s.sizes.items())
            lines.append(f"  {s.name:<10} {s.seconds * 1000:9.1f} ms   {sizes}")
        for k, v in self.timings.items():
            lines.append(f"  {k:<10} {v * 1000:9.1f} ms")
        for k, v in self.speeds.items():
            lines.append(f"  {k}: {v}")
        for k, v in self.penetrations.items():
            lines.append(f"  {k}: {v}")
        if "garment fit" in self.tables:
            lines += ["  garment fit:"] + [f"    {row}" for row in self.tables["garment fit"].splitlines()]
        if self.output:
            lines.append(f"recording: {self.output}  (view: rerun {self.output})")
        lines += [f"exported: {p}" for p in self.exports]
        return "\n".join(lines)

    def markdown(self) -> str:
        """The summary without wall-clock times (those are `timings_markdown`): the same run gives
        the same text."""
        out = [f"# {self.scene}", "", f"{self.frames} frames", "", "| stage | sizes |", "| --- | --- |"]
        for s in self.stages:
            out.append(f"| {s.name} | " + ", ".join(f"{k} {v}" for k, v in s.sizes.items()) + " |")
        if self.penetrations:
            out += ["", "## Penetrations", ""] + [f"- {k}: {v}" for k, v in self.penetrations.items()]
        for name, table in self.tables.items():
            out += ["", f"## {name}", "", table]
        return "\n".join(out)

    def timings_markdown(self) -> str:
        out = ["| stage | wall time (ms) |", "| --- | ---: |"]
        out += [f"| {s.name} | {s.seconds * 1000:.1f} |" for s in self.stages]
        out += [f"| {k} | {v * 1000:.1f} |" for k, v in self.timings.items()]
        out += [""] + [f"- {k}: {v}" for k, v in self.speeds.items()] if self.speeds else []
        return "\n".join(out)


class StageTimer:
    """`with StageTimer(summary, name) as report:` times a stage into the summary (when it does not raise)."""

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
