"""Data contracts of the map stage (paper A §2.3-2.4): per-hull query structures.

Frames
- *bone-local*: the frame of the hull's joint (stages/hulls/types.py). Queries take and return
  bone-local points.
- *OBB-local* (hull-local): origin at the OBB centre, axes = the OBB axes (rows of `axes`), so
  `q = axes @ (p - center)` and `p = center + axes.T @ q`. Axis 0 is the OBB's longest axis `a`:
  the projection direction of the planar meshes, the map sphere's polar axis and the map cylinder's
  axis. Angles: theta = atan2(q2, q1) in [0, 2 pi) around axis 0; the sphere's phi = angle from +axis
  0 in [0, pi]; the cylinder's axial coordinate is q0 (metres).
- *planar (2D)*: the projection plane through the OBB centre perpendicular to `a`, coordinates
  (x, y) = (q1, q2).

Cells of a map are numbered row-major: cell = i_theta * n_second + i_second, where i_second is the
phi interval (sphere) or the axial interval (cylinder).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from stages.checks import ContractError, check_array, check_index
from stages.hulls.types import ConvexMesh

KIND_SPHERE = 0
KIND_CYLINDER = 1
KINDS = {"sphere": KIND_SPHERE, "cylinder": KIND_CYLINDER}


@dataclass(frozen=True)
class SlabLocator:
    """O(log n) point location in one planar mesh: a slab decomposition (Dobkin-Lipton).

    x: (S+1,) float64, strictly increasing slab boundaries (the mesh vertices' x), planar coords, m.
    start: (S+1,) int32, slab j's entries are start[j]..start[j+1] (start[S] = E).
    y: (E, 4) float64, per entry the y of its lower edge at the slab's left and right boundary, then
        of its upper edge at left and right; entries of a slab are sorted bottom to top and do not
        overlap (they tile the slab's part of the convex outline).
    face: (E,) int32, the hull face whose projection the entry belongs to.
    Query: binary search the slab, then the entry whose lower edge is below the point.
    """

    x: np.ndarray
    start: np.ndarray
    y: np.ndarray
    face: np.ndarray

    def __post_init__(self):
        o = "SlabLocator"
        x = check_array(o, "x", self.x, (None,), np.float64)
        if x.size < 2 or not np.all(np.diff(x) > 0):
            raise ContractError(f"{o}.x: expected >= 2 strictly increasing boundaries")
        s = check_array(o, "start", self.start, (x.size,), np.int32)
        e = check_array(o, "y", self.y, (None, 4), np.float64).shape[0]
        check_array(o, "face", self.face, (e,), np.int32)
        if s[0] != 0 or s[-1] != e or np.any(np.diff(s) < 0):
            raise ContractError(f"{o}.start: expected a non-decreasing CSR offset array from 0 to {e}")

    @property
    def slabs(self) -> int:
        return self.x.size - 1


@dataclass(frozen=True)
class HullMap:
    """Query structures of one hull, built once in the bone-local frame (rigid regions never deform).

    mesh: the collider's (simplified) hull, bone-local.
    kind: 'sphere' or 'cylinder' (the map volume; KINDS maps it to the kernels' int code).
    center: (3,) float64, OBB centre, bone-local, m.
    axes: (3, 3) float64, rows = OBB unit axes in bone-local coordinates, right-handed, row 0 the
        longest; from the eigenvectors of the area-weighted covariance of the hull SURFACE
        (Gottschalk et al. 1996, continuous triangle formula).
    half_extents: (3,) float64, m, non-increasing, from the vertices' projections on the axes.
    planes: (m, 4) float64, bone-local, unit outward normal n and offset d per face (inside: n.p <= d).
    planar_vertices: (n, 2) float64, every hull vertex projected on the plane through `center`
        perpendicular to axes[0], planar coordinates (x, y) = (q1, q2), m.
    upper_faces / lower_faces: (mu, 3) / (ml, 3) int32 indices into planar_vertices, the faces with
        n.a > 0 / < 0 (topology kept), counter-clockwise in the plane (lower ones re-oriented);
        faces whose projected area is below a tolerance (n.a ~ 0) are in neither.
    upper_face_ids / lower_face_ids: (mu,) / (ml,) int32, the hull face each planar triangle came from.
    outline: (k,) int32 indices into planar_vertices, the shared convex outline, counter-clockwise.
    upper_locator / lower_locator: point location in the two planar meshes (SlabLocator).
    n_theta: theta intervals over [0, 2 pi); n_second: phi intervals over [0, pi] (sphere) or axial
        intervals over [second_lo, second_hi] = [-half_extents[0], half_extents[0]] m (cylinder).
    cell_start: (C+1,) int32, C = n_theta * n_second, CSR offsets into cell_tris.
    cell_tris: (L,) int32, face indices: every face that some ray from the map source through the
        (closed) cell can hit. Sphere: source = centre, rays = the cell's cone. Cylinder: source =
        the point's projection on the axis, rays perpendicular to the axis, so a cell is a wedge slab.
    """

    mesh: ConvexMesh
    kind: str
    center: np.ndarray
    axes: np.ndarray
    half_extents: np.ndarray
    planes: np.ndarray
    planar_vertices: np.ndarray
    upper_faces: np.ndarray
    upper_face_ids: np.ndarray
    lower_faces: np.ndarray
    lower_face_ids: np.ndarray
    outline: np.ndarray
    upper_locator: SlabLocator
    lower_locator: SlabLocator
    n_theta: int
    n_second: int
    second_lo: float
    second_hi: float
    cell_start: np.ndarray
    cell_tris: np.ndarray

    def __post_init__(self):
        o = "HullMap"
        if self.kind not in KINDS:
            raise ContractError(f"{o}.kind: expected one of {sorted(KINDS)}, got {self.kind!r}")
        check_array(o, "center", self.center, (3,), np.float64)
        r = check_array(o, "axes", self.axes, (3, 3), np.float64)
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
            raise ContractError(f"{o}.axes: expected orthonormal right-handed rows")
        h = check_array(o, "half_extents", self.half_extents, (3,), np.float64)
        if not (h[2] > 0 and h[0] >= h[1] >= h[2]):
            raise ContractError(f"{o}.half_extents: expected positive non-increasing extents, got {h}")
        m = self.mesh.faces.shape[0]
        n = self.mesh.vertices.shape[0]
        check_array(o, "planes", self.planes, (m, 4), np.float64)
        check_array(o, "planar_vertices", self.planar_vertices, (n, 2), np.float64)
        for side in ("upper", "lower"):
            f = check_array(o, f"{side}_faces", getattr(self, f"{side}_faces"), (None, 3), np.int32)
            check_index(o, f"{side}_faces", f, n)
            ids = check_array(o, f"{side}_face_ids", getattr(self, f"{side}_face_ids"), (f.shape[0],), np.int32)
            check_index(o, f"{side}_face_ids", ids, m)
            loc = getattr(self, f"{side}_locator")
            check_index(o, f"{side}_locator.face", loc.face, m)
        if np.intersect1d(self.upper_face_ids, self.lower_face_ids).size:
            raise ContractError(f"{o}: a face is in both the upper and the lower planar mesh")
        ol = check_array(o, "outline", self.outline, (None,), np.int32)
        check_index(o, "outline", ol, n)
        if ol.size < 3:
            raise ContractError(f"{o}.outline: expected >= 3 vertices")
        if self.n_theta < 1 or self.n_second < 1:
            raise ContractError(f"{o}: expected n_theta, n_second >= 1, got {self.n_theta}, {self.n_second}")
        if not self.second_hi > self.second_lo:
            raise ContractError(f"{o}: expected second_lo < second_hi")
        c = self.n_theta * self.n_second
        cs = check_array(o, "cell_start", self.cell_start, (c + 1,), np.int32)
        ct = check_array(o, "cell_tris", self.cell_tris, (None,), np.int32)
        if cs[0] != 0 or cs[-1] != ct.size or np.any(np.diff(cs) < 0):
            raise ContractError(f"{o}.cell_start: expected CSR offsets from 0 to {ct.size}")
        check_index(o, "cell_tris", ct, m)

    @property
    def kind_code(self) -> int:
        return KINDS[self.kind]

    @property
    def cells(self) -> int:
        return self.n_theta * self.n_second

    @property
    def cell_lengths(self) -> np.ndarray:
        """(C,) int: number of triangles listed per cell."""
        return np.diff(self.cell_start)

    @property
    def cell_stats(self) -> dict:
        """Paper A §4 figures: number of cells, longest and mean triangle list."""
        n = self.cell_lengths
        return {"cells": int(n.size), "faces": int(self.mesh.faces.shape[0]),
                "max": int(n.max()), "mean": float(n.mean()), "kind": self.kind}

    def cell_list(self, cell: int) -> np.ndarray:
        return self.cell_tris[self.cell_start[cell]:self.cell_start[cell + 1]]

    def to_local(self, p: np.ndarray) -> np.ndarray:
        """Bone-local points (..., 3) -> OBB-local."""
        return (np.asarray(p, float) - self.center) @ self.axes.T

    def to_bone(self, q: np.ndarray) -> np.ndarray:
        """OBB-local points (..., 3) -> bone-local."""
        return np.asarray(q, float) @ self.axes + self.center


class MapArrays(NamedTuple):
    """Every hull's map packed into flat arrays, the argument `m` of the numba kernels.

    H hulls, F faces in all, C cells in all. Face and cell indices are global (already offset).
    center (H,3) f8, axes (H,3,3) f8 [rows, bone-local], half (H,3) f8: the OBBs (bone-local, m).
    kind (H,) i4: KIND_SPHERE / KIND_CYLINDER. n_theta, n_second (H,) i4; second_lo, second_hi (H,) f8.
    face_start (H+1,) i4: hull h's faces are face_start[h]..face_start[h+1].
    planes (F,4) f8: unit outward normal and offset, OBB-LOCAL frame of the face's hull.
    cell_base (H+1,) i4: hull h's cells are cell_base[h] + (i_theta * n_second + i_second).
    cell_start (C+1,) i4, cell_tris (L,) i4: CSR cell -> global face ids.
    loc_base (2H+1,) i4: planar mesh k = 2h + side (side 0 upper, 1 lower) has slab boundaries
        loc_x[loc_base[k]:loc_base[k+1]].
    loc_x (X,) f8; loc_start (X+1,) i4: the slab whose left boundary is loc_x[g] has entries
        loc_start[g]..loc_start[g+1] (empty for each mesh's last boundary).
    loc_y (E,4) f8, loc_face (E,) i4: as SlabLocator.y / .face, face ids global.
    """

    center: np.ndarray
    axes: np.ndarray
    half: np.ndarray
    kind: np.ndarray
    n_theta: np.ndarray
    n_second: np.ndarray
    second_lo: np.ndarray
    second_hi: np.ndarray
    face_start: np.ndarray
    planes: np.ndarray
    cell_base: np.ndarray
    cell_start: np.ndarray
    cell_tris: np.ndarray
    loc_base: np.ndarray
    loc_x: np.ndarray
    loc_start: np.ndarray
    loc_y: np.ndarray
    loc_face: np.ndarray


def pack_maps(maps: tuple[HullMap, ...]) -> MapArrays:
    """Pack hull maps into MapArrays (face / cell / slab ids offset to global)."""
    if len(maps) == 0:   # a character held by balls alone (every region flexible): the kernels see no hull
        i4, f8 = np.int32, np.float64
        z = lambda *shape, dtype=f8: np.zeros(shape, dtype)   # noqa: E731
        return MapArrays(center=z(0, 3), axes=z(0, 3, 3), half=z(0, 3), kind=z(0, dtype=i4), n_theta=z(0, dtype=i4),
                         n_second=z(0, dtype=i4), second_lo=z(0), second_hi=z(0), face_start=z(1, dtype=i4),
                         planes=z(0, 4), cell_base=z(1, dtype=i4), cell_start=z(1, dtype=i4), cell_tris=z(0, dtype=i4),
                         loc_base=z(1, dtype=i4), loc_x=z(0), loc_start=z(1, dtype=i4), loc_y=z(0, 4),
                         loc_face=z(0, dtype=i4))
    planes, cell_start, cell_tris, loc_x, loc_start, loc_y, loc_face = [], [0], [], [], [], [], []
    face_start, cell_base, loc_base = [0], [0], [0]
    e0 = 0
    for hm in maps:
        f0 = face_start[-1]
        n = hm.planes[:, :3] @ hm.axes.T  # normals in OBB-local
        d = hm.planes[:, 3] - hm.planes[:, :3] @ hm.center
        planes.append(np.column_stack([n, d]))
        face_start.append(f0 + hm.planes.shape[0])
        l0 = cell_start[-1]
        cell_start.extend((l0 + hm.cell_start[1:]).tolist())
        cell_tris.append(hm.cell_tris + f0)
        cell_base.append(cell_base[-1] + hm.cells)
        for loc in (hm.upper_locator, hm.lower_locator):
            # start[S] of one mesh = start[0] of the next: the last boundary opens no slab
            loc_start.extend((e0 + loc.start).tolist())
            e0 += loc.y.shape[0]
            loc_x.append(loc.x)
            loc_y.append(loc.y)
            loc_face.append(loc.face + f0)
            loc_base.append(loc_base[-1] + loc.x.size)
    i4 = np.int32
    return MapArrays(
        center=np.array([hm.center for hm in maps]),
        axes=np.array([hm.axes for hm in maps]),
        half=np.array([hm.half_extents for hm in maps]),
        kind=np.array([hm.kind_code for hm in maps], i4),
        n_theta=np.array([hm.n_theta for hm in maps], i4),
        n_second=np.array([hm.n_second for hm in maps], i4),
        second_lo=np.array([hm.second_lo for hm in maps], float),
        second_hi=np.array([hm.second_hi for hm in maps], float),
        face_start=np.array(face_start, i4),
        planes=np.ascontiguousarray(np.concatenate(planes)),
        cell_base=np.array(cell_base, i4),
        cell_start=np.array(cell_start, i4),
        cell_tris=np.concatenate(cell_tris).astype(i4),
        loc_base=np.array(loc_base, i4),
        loc_x=np.concatenate(loc_x),
        loc_start=np.array(loc_start + [e0], i4),
        loc_y=np.ascontiguousarray(np.concatenate(loc_y)),
        loc_face=np.concatenate(loc_face).astype(i4),
    )


@dataclass(frozen=True)
class MapSet:
    """The maps of every hull collider of a character.

    maps: one HullMap per hull, in ColliderSet.hulls order (hull index h).
    bones: (H,) int32, joint index whose bone-local frame hull h is in; names: the joints' names.
    arrays: MapArrays, the packed form the numba kernels take (`m`).
    """

    maps: tuple
    bones: np.ndarray
    names: tuple
    arrays: MapArrays

    def __post_init__(self):
        o = "MapSet"
        h = len(self.maps)
        check_array(o, "bones", self.bones, (h,), np.int32)
        if len(self.names) != h:
            raise ContractError(f"{o}.names: expected {h} names, got {len(self.names)}")
        a = self.arrays
        if a.center.shape != (h, 3) or a.face_start.shape != (h + 1,) or a.loc_base.shape != (2 * h + 1,):
            raise ContractError(f"{o}.arrays: packed arrays do not describe {h} hulls")
        if a.loc_start.shape != (a.loc_x.size + 1,) or a.cell_start.shape != (a.cell_base[-1] + 1,):
            raise ContractError(f"{o}.arrays: inconsistent CSR offsets")
        check_index(o, "arrays.cell_tris", a.cell_tris, int(a.face_start[-1]))
        check_index(o, "arrays.loc_face", a.loc_face, int(a.face_start[-1]))

    @classmethod
    def from_maps(cls, maps, bones=None, names=None) -> "MapSet":
        maps = tuple(maps)
        bones = np.arange(len(maps), dtype=np.int32) if bones is None else np.asarray(bones, np.int32)
        names = tuple(f"hull{i}" for i in range(len(maps))) if names is None else tuple(names)
        return cls(maps=maps, bones=bones, names=names, arrays=pack_maps(maps))
