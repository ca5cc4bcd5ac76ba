"""The floor under the cloth (SimParams.floor, stages.sim.floor): the kernel against a plain-Python
reference, a sheet resting on it, a hopping character's cloth kept above the world floor, no floor
the old result; the pipeline's `simulation.floor` key."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.garments.simple import rectangle_cloth
from stages.garments.types import attach_indices, bind_pose, build_garment
from stages.sim import SimParams, simulate
from stages.sim.floor import collide_floor, floor_heights
from stages.sim.scenes import toy_character, toy_motion

TRI = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int32)
TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.01 - 5.0  # a far-away body


def reference_floor(x, xp, inv_mass, attach_joint, f0, f1, d_next, friction):
    """The floor response written out per particle in plain Python."""
    x, xp = x.copy(), xp.copy()
    for i in range(len(x)):
        if inv_mass[i] == 0 or attach_joint[i] >= 0 or not x[i][1] < f1:
            continue
        depth = f1 - x[i][1]
        x[i][1] = f1
        travel = [x[i][0] - xp[i][0] + d_next[0], x[i][2] - xp[i][2] + d_next[2]]
        length = (travel[0] ** 2 + travel[1] ** 2) ** 0.5
        if friction > 0 and length > 0:
            c = min(1.0, friction * depth / length)
            x[i][0] -= c * travel[0]
            x[i][2] -= c * travel[1]
        if f0 - xp[i][1] > 0:
            xp[i][1] = f0
    return x, xp


coord = st.floats(-0.5, 0.5, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(0, 2 ** 32 - 1), coord, coord, st.floats(0.0, 2.0))
def test_kernel_matches_the_reference(n, seed, f0, f1, friction):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.6, 0.6, (n, 3))
    xp = x + rng.normal(0, 0.05, (n, 3))
    inv_mass = np.where(rng.random(n) < 0.2, 0.0, 1.0)
    attach = np.where(rng.random(n) < 0.2, 0, -1).astype(np.int32)
    d_next = rng.normal(0, 0.01, 3)
    want_x, want_xp = reference_floor(x, xp, inv_mass, attach, f0, f1, d_next, friction)
    floor = np.array([9.0, f0, f1])      # step k = 1 reads floor[1], floor[2]
    collide_floor(x, xp, inv_mass, attach, floor, 1, d_next, friction)
    np.testing.assert_allclose(x, want_x, atol=1e-12)
    np.testing.assert_allclose(xp, want_xp, atol=1e-12)
    free = (inv_mass > 0) & (attach < 0)
    assert (x[free, 1] >= f1).all()


def test_floor_heights_follow_the_root_between_frames():
    root_y = np.array([0.0, 0.3, 0.1, 0.4])
    h = floor_heights(root_y, 2, 4, 4, 0.05)
    # frames 2 and 3: from root 0.3 to 0.1 to 0.4 in quarter steps, the floor world 0.05 minus the root
    want = 0.05 - np.array([0.3, 0.25, 0.2, 0.15, 0.1, 0.175, 0.25, 0.325, 0.4])
    np.testing.assert_allclose(h, want, atol=1e-12)


def _sheet(y=0.3, n=10):
    x, tri = rectangle_cloth(0.5, 0.5, n, n, center=(0, y, 0))
    ch = toy_character(TET, TRI)
    return ch, build_garment("sheet", x, tri)


def test_a_sheet_dropped_on_the_floor_rests_on_it():
    ch, g = _sheet()
    params = SimParams(body_audit=False, floor=0.1)
    r = simulate(ch, toy_motion(60), None, None, [g], params)
    y = r.garments[0].positions[..., 1]
    rest = 0.1 + 0.5 * params.cloth_thickness
    assert y.min() >= rest - 1e-6                                   # never under it
    np.testing.assert_allclose(y[-1], rest, atol=1e-6)              # lying flat on it
    p = r.garments[0].positions
    assert np.abs(p[-1] - p[-5]).max() < 1e-6                       # settled: no jitter


@pytest.mark.parametrize("inertia", [0.0, 1.0])
def test_a_hopping_characters_cloth_stays_above_the_world_floor(inertia):
    """A flag pinned to a root that hops 30 cm up and lands twice (toy_motion puts the root at world 0
    at frame 0): its hem, 15 cm longer than its top is high, rests on the floor at the landings and
    never goes under it (world frame)."""
    n = 90
    t = np.arange(n) / 30
    hop = 0.3 * np.abs(np.sin(np.pi * t / 1.5))            # two hops of 1.5 s, 30 cm high
    root = np.stack([0.2 * t, hop, np.zeros(n)], axis=1)
    x, tri = rectangle_cloth(0.3, 0.6, 8, 14, center=(0, 0.15, 0), normal=(0, 0, 1))
    top = np.flatnonzero(np.isclose(x[:, 1], x[:, 1].max()))
    ch, mo = toy_character(TET, TRI), toy_motion(n, root_translation=root)
    g = build_garment("flag", x, tri, attachments=[attach_indices(top, "root")], bind=bind_pose(ch, mo))
    params = SimParams(body_audit=False, floor=0.0, inertia_scale=inertia)
    y = simulate(ch, mo, None, None, [g], params).garments[0].positions[..., 1]
    rest = 0.5 * params.cloth_thickness
    assert y[1:].min() >= rest - 1e-5           # frame 0: where the scene put it (no settling frames here)
    assert np.isclose(y[1:].min(axis=1), rest, atol=1e-5).sum() >= 5    # it lies on the floor at the landings
    free = simulate(ch, mo, None, None, [g], SimParams(body_audit=False, inertia_scale=inertia))
    assert free.garments[0].positions[..., 1].min() < -0.1             # without it, through the floor


def test_a_floor_under_everything_changes_nothing():
    """No particle ever under the floor: the result is the one without a floor, bit for bit."""
    x, tri = rectangle_cloth(0.5, 0.5, 10, 10, center=(0, 1, 0), normal=(0, 0, 1))
    top = np.flatnonzero(np.isclose(x[:, 1], x[:, 1].max()))
    ch, mo = toy_character(TET, TRI), toy_motion(30)
    g = build_garment("flag", x, tri, attachments=[attach_indices(top, "root")], bind=bind_pose(ch, mo))
    a = simulate(ch, mo, None, None, [g], SimParams(body_audit=False))
    b = simulate(ch, mo, None, None, [g], SimParams(body_audit=False, floor=-5.0))
    assert np.array_equal(a.garments[0].positions, b.garments[0].positions)


def test_floor_params_are_checked():
    from stages.checks import ContractError
    with pytest.raises(ContractError, match="floor"):
        SimParams(floor=float("nan"))
    assert SimParams().floor is None and SimParams.preset("paper").floor is None
