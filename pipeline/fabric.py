"""A garment's `material` (issue 39, part 4): a named fabric or a GarmentCode simulator settings file,
resolved once the scene is validated into the garment's density and stiffnesses; keys the garment
states itself override the material's."""
from __future__ import annotations

from pathlib import Path

import yaml

from pipeline.schema import SceneError, expand_path_vars
from stages.errors import InputError
from stages.garments.fabrics import FABRICS, Fabric, fabric_from_sim_props

DEFAULT_DENSITY = 0.2    # kg/m^2, a garment with neither a density nor a material
FABRIC_KEYS = ("density", "stretch_stiffness", "bend_stiffness")


def check_material(v) -> str | None:
    """The schema's check of a `material` value (the file itself is read by `resolve_fabrics`)."""
    if v is None or (isinstance(v, str) and v in FABRICS):
        return None
    if isinstance(v, dict) and set(v) == {"file"} and isinstance(v["file"], str) and v["file"]:
        return None
    return (f"expected one of {', '.join(FABRICS)} or {{file: a GarmentCode simulator settings file}}, "
            f"got {v!r}")


def read_sim_props(path: Path, where: str) -> Fabric:
    """The Fabric of a GarmentCode simulator settings file (YAML or JSON): its sim.config.material
    section, or a top-level `material` mapping."""
    from stages.input_files import read_text_file
    from stages.safe_yaml import load_checked
    try:
        text = read_text_file(path, "material file", SceneError)
    except SceneError as err:
        raise SceneError(f"{where}: {err}") from None
    try:
        data, _ = load_checked(text, str(path), SceneError)    # no alias bomb, no endless nesting
    except SceneError as err:
        raise SceneError(f"{where}: {err}") from None
    except yaml.YAMLError as err:
        raise SceneError(f"{where}: {path}: cannot parse the material file: {str(err).splitlines()[0]}") from None
    sim = data.get("sim") if isinstance(data, dict) else None
    config = sim.get("config") if isinstance(sim, dict) else None
    material = config.get("material") if isinstance(config, dict) else (
        data.get("material") if isinstance(data, dict) else None)
    if not isinstance(material, dict):
        raise SceneError(f"{where}: {path}: no material section (expected sim: config: material: as in "
                         f"GarmentCode's default_sim_props.yaml)")
    try:
        return fabric_from_sim_props(material, str(path))
    except InputError as err:
        raise SceneError(f"{where}: {err}") from None


def garment_fabric(g: dict, where: str, base_dir: Path | None) -> Fabric | None:
    """The fabric a garment's `material` names, or None."""
    m = g.get("material")
    if m is None:
        return None
    if isinstance(m, str):
        return FABRICS[m]
    p = Path(expand_path_vars(m["file"])).expanduser()
    return read_sim_props(p if p.is_absolute() or base_dir is None else base_dir / p, where)


def resolve_fabrics(settings: dict, source: str, base_dir: Path | None) -> None:
    """Fill each garment's density, stretch_stiffness and bend_stiffness: its own keys first, then
    its material's, then DEFAULT_DENSITY (stiffness None: the simulation's)."""
    for i, g in enumerate(settings.get("garments") or ()):
        fabric = garment_fabric(g, f"{source}: garments[{i}].material", base_dir)
        for key in FABRIC_KEYS:
            if g.get(key) is None and fabric is not None and getattr(fabric, key) == getattr(fabric, key):  # nan: not given
                g[key] = getattr(fabric, key)
        if g.get("density") is None:
            g["density"] = DEFAULT_DENSITY
