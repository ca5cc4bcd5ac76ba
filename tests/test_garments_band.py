"""Limbs that rest on a garment's attached band pass through the garment (stages.garments.band): which
limbs a garment wraps, which rest on its band, and that the simulation lets them through."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.garments.band import REST_SHARE, band_contacts, resting_limbs, wraps
from stages.garments.simple import tube_skirt
from stages.garments.types import attach_top_loop, bind_pose, build_garment
from stages.hulls.types import ColliderSet, SphereCollider
from stages.rig.types import Motion
from stages.sim import SimParams, simulate
from tests.test_sim_yield import root_and_arm

RADIUS, DELTA = 0.1, 0.01
N_FRAMES = 40


def _cylinder(axis, centre, length, radius, rings=8, around=8):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t, a = np.meshgrid(np.linspace(-length / 2, length / 2, rings), np.linspace(0, 2 * np.pi, around, endpoint=False))
    return (np.asarray(centre, float) + t.reshape(-1, 1) * axis
            + radius * (np.cos(a).reshape(-1, 1) * u + np.sin(a).reshape(-1, 1) * v))


ARM = _cylinder([1, 0, 0], [0.32, 0.4, 0], 0.3, 0.04)          # an arm held out along +x
SLEEVE = _cylinder([1, 0, 0], [0.3, 0.4, 0], 0.15, 0.06)
SKIRT = _cylinder([0, 1, 0], [0, 0.0, 0], 0.3, 0.16, around=24)  # round the body below the arm
ORIGIN = np.array([0.17, 0.4, 0.0])                              # the arm's joint (its shoulder)


def test_a_sleeve_wraps_the_arm_and_a_skirt_does_not():
    assert wraps(SLEEVE, ARM, ORIGIN, None)
    assert wraps(SLEEVE, ARM, ORIGIN, ORIGIN + [0.3, 0.0, 0.0])        # the axis towards a child joint
    assert not wraps(SKIRT, ARM, ORIGIN, None)
    assert not wraps(SLEEVE + [0.0, 1.0, 0.0], ARM, ORIGIN, None)      # nothing level with the arm
    # four points round the arm are enough (a coarse sleeve); three on one side are not
    ring = _cylinder([1, 0, 0], [0.3, 0.4, 0], 0.0, 0.06, rings=1, around=4)
    assert wraps(ring, ARM, ORIGIN, None) and not wraps(ring[:3], ARM, ORIGIN, None)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 2 * np.pi), st.floats(-1.0, 1.0), st.floats(0.2, 3.0))
def test_wrapping_does_not_depend_on_how_the_body_is_turned_or_sized(yaw, tilt, scale):
    c, s = np.cos(yaw), np.sin(yaw)
    r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ np.array(
        [[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    f = lambda p: scale * np.asarray(p) @ r.T     # noqa: E731
    assert wraps(f(SLEEVE), f(ARM), f(ORIGIN), None)
    assert not wraps(f(SKIRT), f(ARM), f(ORIGIN), None)


def _scene(rest_from: int, centre=(0.3, 1.0, 0.0), away=(1.2, 1.0, 0.0), radius=RADIUS):
    """Joint 'root' still; joint 'arm' carries a sphere (`radius`), away from a skirt pinned to the
    root (top ring: radius 0.3 at y = 1) until frame `rest_from`, then lying on its waistband at
    `centre`."""
    ch = root_and_arm()
    jw = np.tile(np.eye(4), (N_FRAMES, 2, 1, 1))
    jw[:, 1, :3, 3] = away
    jw[rest_from:, 1, :3, 3] = centre
    mo = Motion("rest", np.arange(N_FRAMES) / 30.0, jw, np.zeros((N_FRAMES, 3)))
    cs = ColliderSet(hulls=(), spheres=(SphereCollider(1, "arm", np.zeros(3), radius, np.zeros((0, 3))),),
                     delta=DELTA, min_triangles=4)
    x, tri = tube_skirt(0.3, 0.35, 0.3, 24, 4, center=(0.0, 1.0, 0.0))
    return ch, mo, cs, x, tri


def _band(rest_from, centre, away):
    """A big sphere (0.35) on the skirt's band: (bind pose, skirt points, its band's points and joints,
    the sphere's band_contacts)."""
    ch, mo, cs, x, tri = _scene(rest_from, centre=centre, away=away, radius=0.35)
    bind = bind_pose(ch, mo, cs)
    top = np.flatnonzero(np.isclose(x[:, 1], 1.0))
    joints = np.zeros(top.size, np.int32)
    return bind, x, x[top], joints, band_contacts(bind, x[top], joints, DELTA)


def _build(rest_from, **kw):
    ch, mo, cs, x, tri = _scene(rest_from, **kw)
    bind = bind_pose(ch, mo, cs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = build_garment("skirt", x, tri, attachments=[attach_top_loop("root")], bind=bind)
    return ch, mo, cs, g, [str(w.message) for w in caught]


@pytest.mark.parametrize("rest_from", [4, 10, 19])
def test_a_limb_lying_on_the_band_in_most_frames_passes_through(rest_from):
    assert (N_FRAMES - rest_from) / N_FRAMES >= REST_SHARE
    _, _, _, g, said = _build(rest_from)
    assert g.passing_joints == (1,)
    assert any("arm rest on its attached band" in s for s in said)
    assert not g.yielding.size      # the band stays on its bone: the limb does not push it
    assert not any("yield" in s for s in said)


@pytest.mark.parametrize("rest_from", [21, 30])
def test_a_limb_that_only_passes_the_band_pushes_it(rest_from):
    _, _, _, g, said = _build(rest_from)
    assert g.passing_joints == ()
    assert g.yielding.size and any("yield to collisions: the colliders arm" in s for s in said)


def test_a_limb_the_garment_wraps_never_passes():
    # the sphere inside the skirt, bigger than its waist: it holds the whole band at every frame,
    # but the skirt is round it (a thigh in a skirt)
    bind, x, band, joints, contacts = _band(0, centre=(0.0, 1.0, 0.0), away=(0.0, 1.0, 0.0))
    (bone, _, held, frames), = contacts
    assert bone == 1 and held.all() and frames.all()
    assert resting_limbs(bind, x, band, joints, DELTA) == []


def test_the_trunk_never_passes():
    # a bone above the skirt at frame 0 (not wrapped), then resting on its whole band from above, the
    # band's centre line through it: a chest behind a high waistband, not a limb beside the body
    bind, x, band, joints, contacts = _band(10, centre=(0.0, 1.1, 0.0), away=(0.0, 1.6, 0.0))
    (_, _, _, frames), = contacts
    assert frames.mean() >= REST_SHARE
    assert resting_limbs(bind, x, band, joints, DELTA) == []


def test_the_simulation_lets_a_passing_limb_through():
    from dataclasses import replace
    ch, mo, cs, g, _ = _build(10, centre=(0.32, 0.94, 0.0))     # on the band and the cloth below it
    params = SimParams(substeps=4, iterations=2, body_audit=False)
    centre = mo.joint_world[-1, 1, :3, 3]
    free = g.inverse_mass > 0

    def inside_at_end(garment):
        res = simulate(ch, mo, cs, None, [garment], params)
        x = res.garments[0].positions[-1]
        assert np.isfinite(x).all()
        return res, int((np.linalg.norm(x[free] - centre, axis=1) < RADIUS - 1e-3).sum())

    res, passed = inside_at_end(g)
    assert any("not pushed by the colliders of arm" in n for n in res.notes)
    _, pushed = inside_at_end(replace(g, passing_joints=()))
    assert passed > 0 and pushed == 0     # passing through, the cloth stays under the limb; else pushed out
