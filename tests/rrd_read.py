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


LISTS = {"ContainerBlueprint:contents", "ViewContents:query", "ContainerBlueprint:col_shares",
         "ContainerBlueprint:row_shares"}


def blueprint(path: Path) -> dict:
    """The recording's stored blueprint (the last one in the file): {entity path: {column: value}},
    e.g. bp['/time_panel']['TimePanelBlueprint:timeline'] == 'frame'. Lists of one are unwrapped."""
    reader = RrdReader(path)
    stores = reader.blueprints()
    if not stores:
        return {}
    out: dict = {}
    for chunk in reader.stream(store=stores[-1]).to_chunks():
        batch = chunk.to_record_batch()
        entry = out.setdefault(str(chunk.entity_path), {})
        for name in batch.schema.names:
            if ":" not in name:   # row ids, the blueprint / log_time indexes
                continue
            for v in batch.column(name).to_pylist():
                if v is not None:
                    entry[name] = v[0] if isinstance(v, list) and len(v) == 1 and name not in LISTS else v
    return out


def blueprint_views(bp: dict) -> dict:
    """{view display name: {'id', 'class', 'origin', 'contents', 'eye': (position, look_target) or None}}."""
    views = {}
    for path, comp in bp.items():
        if path.startswith("/view/") and path.count("/") == 2 and "ViewBlueprint:class_identifier" in comp:
            eye = bp.get(f"{path}/EyeControls3D", {})
            views[comp.get("ViewBlueprint:display_name")] = {
                "id": path.split("/")[2], "class": comp["ViewBlueprint:class_identifier"],
                "origin": comp.get("ViewBlueprint:space_origin"),
                "contents": bp.get(f"{path}/ViewContents", {}).get("ViewContents:query", []),
                "eye": (np.array(eye["EyeControls3D:position"]), np.array(eye["EyeControls3D:look_target"]))
                if "EyeControls3D:position" in eye else None}
    return views


def blueprint_tabs(bp: dict) -> dict:
    """{tab name: [view ids in it]}, in tab order, and the active tab's entry under key None."""
    def kids(entry):
        return bp.get("/" + entry, {}).get("ContainerBlueprint:contents", []) or []

    def name(entry):
        c = bp.get("/" + entry, {})
        return c.get("ContainerBlueprint:display_name") or c.get("ViewBlueprint:display_name")

    def views(entry):
        if entry.startswith("view/"):
            return [entry.split("/")[1]]
        return [v for k in kids(entry) for v in views(k)]
    tabs = next(p for p, c in bp.items() if c.get("ContainerBlueprint:container_kind") == TABS_KIND)
    out = {name(e): views(e) for e in kids(tabs[1:])}
    out[None] = name(bp[tabs].get("ContainerBlueprint:active_tab") or kids(tabs[1:])[0])
    return out


TABS_KIND = 1   # rerun.blueprint.components.ContainerKind.Tabs
