"""Region split: hand-built weights with known answers, invariants on random rigs, CesiumMan."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from stages.rig.gltf import load_gltf
from stages.rig.regions import region_report, split_regions
from stages.rig.transforms import forward_kinematics, trs_to_matrix
from stages.rig.types import Character

#  joints: 0 root -> 1 -> 2 ; 0 -> 3   (depths 0, 1, 2, 1)
PARENTS = np.array([-1, 0, 1, 0], np.int32)
JOINT_POS = np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0], [1, 0, 0]], float)


def character(groups) -> Character:
    """groups: list of (points (n, 3), joints (4,), weights (4,)) -> a Character with those weights."""
    rest_local = trs_to_matrix(np.array([JOINT_POS[0]] + [JOINT_POS[j] - JOINT_POS[PARENTS[j]] for j in range(1, 4)]),
                               np.tile([0, 0, 0, 1.0], (4, 1)))
    verts, sj, sw = [], [], []
    for pts, j, w in groups:
        verts.append(pts)
        sj.append(np.tile(j, (len(pts), 1)))
        sw.append(np.tile(np.asarray(w, float) / np.sum(w), (len(pts), 1)))
    v = np.concatenate(verts).astype(np.float64)
    return Character(
        name="hand", vertices=v, triangles=np.zeros((0, 3), np.int32), primitive_ids=np.zeros(len(v), np.int32),
        joint_names=("root", "spine", "head", "side"), parents=PARENTS, rest_local=rest_local,
        inverse_bind=np.linalg.inv(forward_kinematics(PARENTS, rest_local)),
        skin_joints=np.concatenate(sj).astype(np.int32), skin_weights=np.concatenate(sw))


def blob(rng, n, centre, flat=False):
    p = rng.normal(0, 0.1, (n, 3)) + centre
    if flat:
        p[:, 2] = centre[2]
    return p


@pytest.fixture
def hand_split():
    rng = np.random.default_rng(0)
    groups = [
        (blob(rng, 10, [0, 0.3, 0]), [0, 1, 2, 3], [1, 0, 0, 0]),          # rigid on root
        (blob(rng, 8, [0, 1.0, 0]), [1, 0, 2, 3], [0.6, 0.4, 0, 0]),       # parent/child 0-1 -> joint 1
        (blob(rng, 5, [0.5, 0.5, 0]), [1, 3, 0, 2], [0.7, 0.3, 0, 0]),     # siblings 1, 3 (same depth) -> 3
        (blob(rng, 5, [0.5, 1.5, 0]), [3, 2, 0, 1], [0.55, 0.45, 0, 0]),   # 3 (depth 1) vs 2 (depth 2) -> 2
        (blob(rng, 3, [0, 2.3, 0]), [2, 0, 1, 3], [1, 0, 0, 0]),           # 3 rigid points: too few
        (blob(rng, 6, [1.2, 0, 0], flat=True), [3, 0, 1, 2], [1, 0, 0, 0]),  # flat rigid region
        (blob(rng, 6, [0, 1.3, 0]), [1, 1, 0, 2], [0.5, 0.5, 0, 0]),      # joint repeated: rigid on 1
    ]
    c = character(groups)
    return c, split_regions(c, threshold=0.9)


def test_hand_split_known_answers(hand_split):
    c, s = hand_split
    rj = s.region_joint
    assert s.rigid[:10].all() and (rj[:10] == 0).all()
    assert not s.rigid[10:18].any() and (rj[10:18] == 1).all()
    assert (rj[18:23] == 3).all() and not s.rigid[18:23].any()
    assert (rj[23:28] == 2).all() and not s.rigid[23:28].any()
    # too few: merged into the flexible region of the nearest joint among head (2) and its children
    assert not s.rigid[28:31].any() and (rj[28:31] == 2).all()
    # flat: bone 3 has no children, so its own joint
    assert not s.rigid[31:37].any() and (rj[31:37] == 3).all()
    assert s.rigid[37:].all() and (rj[37:] == 1).all() and np.allclose(s.dominant_weight[37:], 1.0)
    assert s.hull_bones == (0, 1)
    assert s.sphere_joints == (1, 2, 3)
    assert len(s.notes) == 2
    assert "bone 2 (head): 3 vertices, fewer than 4 points" in s.notes[0]
    assert "bone 3 (side): 6 vertices, flat" in s.notes[1]
    rows = region_report(s, c.joint_names)
    assert sum(r["vertices"] for r in rows) == c.vertices.shape[0]
    assert {"kind": "rigid", "joint": 0, "name": "root", "vertices": 10} in rows
    assert region_report(s)[0]["name"] == "joint_0"


def test_threshold_one_and_half(hand_split):
    c, _ = hand_split
    s1 = split_regions(c, threshold=1.0)
    s05 = split_regions(c, threshold=0.5)
    # at 0.5 the 0.6 / 0.7 / 0.55 blends become rigid too
    assert s05.rigid[10:28].all() and not s1.rigid[10:28].any()
    assert set(s1.hull_bones) <= set(s05.hull_bones)
    assert np.all(s1.rigid <= s05.rigid)


def check_partition(c: Character, s) -> None:
    seen = np.zeros(c.vertices.shape[0], int)
    for b in s.hull_bones:
        idx = s.rigid_vertices(b)
        seen[idx] += 1
        pts = c.vertices[idx]
        assert len(idx) >= 4
        assert ConvexHull(pts).volume > 0  # a 3D hull exists (independent of the rank test)
    for j in s.sphere_joints:
        idx = s.flexible_vertices(j)
        assert len(idx) > 0
        seen[idx] += 1
    assert np.all(seen == 1)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 100_000), threshold=st.sampled_from([0.5, 0.8, 0.9, 1.0]))
def test_random_rigs_partition(seed, threshold):
    rng = np.random.default_rng(seed)
    groups = []
    for _ in range(int(rng.integers(1, 8))):
        n = int(rng.integers(1, 9))
        j = rng.permutation(4)
        w = rng.uniform(0, 1, 4) * (rng.uniform(size=4) < 0.5)
        w[0] += rng.choice([0.0, 5.0])  # often one dominant influence
        w[0] += 1e-3
        groups.append((blob(rng, n, rng.normal(0, 1, 3), flat=bool(rng.integers(0, 2))), j, w))
    c = character(groups)
    s = split_regions(c, threshold=threshold)
    check_partition(c, s)
    s_low = split_regions(c, threshold=0.5)
    if threshold == 1.0:
        assert np.all(s.rigid <= s_low.rigid)


@pytest.fixture(scope="module")
def cesium(assets_dir):
    return load_gltf(assets_dir / "CesiumMan.glb")


@pytest.mark.parametrize("threshold", [0.5, 0.9, 1.0])
def test_cesium_man_regions(cesium, threshold):
    s = split_regions(cesium, threshold=threshold)
    check_partition(cesium, s)
    rows = region_report(s, cesium.joint_names)
    assert sum(r["vertices"] for r in rows) == 3273
    assert len(s.hull_bones) >= 5


def test_cesium_man_threshold_monotone(cesium):
    s1, s05 = split_regions(cesium, 1.0), split_regions(cesium, 0.5)
    assert np.all(s1.rigid <= s05.rigid)
    assert s05.rigid.sum() > 2 * s1.rigid.sum()
