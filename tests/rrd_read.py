"""Read a recording back with the SDK's own reader (rerun-sdk 0.41: rerun.chunk.RrdReader)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader


def store(path: Path):
    return RrdReader(path).store()


def entity_paths(path: Path) -> set[str]:
    return set(store(path).schema().entity_paths())


def timelines(path: Path) -> set[str]:
    return {str(i).split("timeline:")[-1].rstrip(")") for i in store(path).schema().index_columns()}


def rows(path: Path, entity: str, component: str, *, static: bool | None = None):
    """[(frame or None, value as a numpy array)] for every row that has `component`, sorted by frame.

    component: the column name, e.g. 'Mesh3D:vertex_positions', 'Scalars:scalars', 'TextDocument:text'.
    """
    stream = store(path).stream().filter(content=entity if entity.startswith("/") else "/" + entity)
    out = []
    for chunk in stream.to_chunks():
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        frames = batch.column("frame").cast("int64").to_pylist() if "frame" in batch.schema.names else [None] * batch.num_rows
        if static is True and "frame" in batch.schema.names or static is False and "frame" not in batch.schema.names:
            continue
        for f, v in zip(frames, batch.column(component).to_pylist()):
            if v is None:
                continue
            out.append((f, np.asarray(v[0] if isinstance(v, list) and len(v) == 1 and component.endswith(":text") else v)))
    out.sort(key=lambda r: -1 if r[0] is None else r[0])
    return out


def content(path: Path) -> list:
    """Every chunk as (entity, record batch without row ids), in a stable order: the recording's
    content with the per-write random ids removed."""
    out = []
    for chunk in store(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        keep = [n for n in batch.schema.names if n != "rerun.controls.RowId"]
        out.append((str(chunk.entity_path), batch.select(keep)))
    out.sort(key=lambda e: (e[0], e[1].schema.names, e[1].num_rows))
    return out


def same_content(a: Path, b: Path) -> bool:
    ca, cb = content(a), content(b)
    return len(ca) == len(cb) and all(ea == eb and ba.equals(bb) for (ea, ba), (eb, bb) in zip(ca, cb))
