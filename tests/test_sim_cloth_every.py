"""The cloth x cloth phase called once every few sub-steps (SimParams.cloth_contact_every > 1,
stages.sim.step.cloth_phase): the sub-steps between calls project the contacts the last call found,
so a layer resting on another is held there instead of falling into the gap and being caught by the
next call's continuous test."""
from __future__ import annotations

import numpy as np
import pytest

from stages.sim import step
from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.phase import ClothPhase
from tests.test_sim_cloth_contact import H, two_sheets

EVERY = 4
DT = 1.0 / 120.0   # over EVERY sub-steps a sheet falls g (EVERY DT)^2 / 2 = 5.4 mm from rest, past the gap


def rest_on_lower_sheet(keep_contacts: bool):
    """The upper of two 9 x 9 sheets (10 cm, layers 0 / 1) starts at rest H above the pinned lower
    one and falls under gravity for 40 sub-steps, the phase called every EVERY. Returns the upper
    sheet's lowest interior height after every sub-step (m) and the counters."""
    x, t, off, layers = two_sheets(n=9, gap=1.05 * H)
    cinv = np.ones(len(x))
    cinv[:off[1]] = 0.0
    phase = ClothPhase(x, t, off, cinv, np.array(layers), None, H, EVERY, H)
    xp = x.copy()
    top = np.arange(off[1], off[2])
    inner = top[(x[top, 0] > 0.015) & (x[top, 0] < 0.085) & (x[top, 2] > 0.015) & (x[top, 2] < 0.085)]
    lowest = []
    for k in range(40):
        if k % EVERY == 0:
            phase.x_start[:] = x
        elif not keep_contacts:
            phase.keep[7][0] = 0     # the control: nothing held between calls
        v = x[top] - xp[top]
        xp[top] = x[top]
        x[top] += v
        x[top, 1] -= 9.81 * DT * DT
        step.cloth_phase(x, xp, k, phase.rest)
        lowest.append(x[inner, 1].min())
    return np.array(lowest), phase.counters


def test_kept_contacts_hold_a_resting_layer_between_calls():
    lowest, counters = rest_on_lower_sheet(True)
    assert lowest[EVERY:].min() > 0.9 * H               # every sub-step after the first call, not only the calls
    assert counters[CK.N_UNRESOLVED] == 0 and counters[CK.N_REVERTED] == 0
    assert counters[CK.N_CONTACTS] > 0


def test_control_without_kept_contacts_the_layer_falls_into_the_gap():
    lowest, counters = rest_on_lower_sheet(False)
    assert lowest.min() < 0.0      # through the lower sheet's plane between calls


def test_the_calls_keep_the_layers_apart():
    lowest, counters = rest_on_lower_sheet(True)
    assert lowest[EVERY - 1::EVERY].min() > 0.9 * H      # after each call
    assert counters[CK.N_LEFT] == 0


def test_sub_steps_per_call_divide_the_frame():
    from stages.checks import ContractError
    from stages.sim.types import SimParams
    assert SimParams(substeps=20, cloth_contact_every=5).contact_steps() == 5
    assert SimParams(substeps=12, cloth_contact_every=5).contact_steps() == 4   # the largest divisor up to it
    assert SimParams(substeps=1, cloth_contact_every=5).contact_steps() == 1    # the paper preset's one step
    assert SimParams(substeps=7, cloth_contact_every=5).contact_steps() == 1
    for bad in (0, True, 2.5):
        try:
            SimParams(cloth_contact_every=bad)
        except ContractError as err:
            assert "cloth_contact_every" in str(err)
        else:
            raise AssertionError(f"{bad!r} accepted")


def _contact_buffer(n, idx, w, d):
    return (np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(0, np.int8), np.zeros((0, 2), np.int32),
            np.ascontiguousarray(idx, np.int32), np.ascontiguousarray(w, np.float64), np.ascontiguousarray(d, np.float64))


def test_bounded_projection_is_respond_where_every_particle_moves():
    from stages.sim.cloth_contact.response import respond
    rng = np.random.default_rng(7)
    n, m = 40, 60
    x = rng.normal(scale=0.004, size=(n, 3))
    idx = np.array([rng.choice(n, 4, replace=False) for _ in range(m)])
    w = np.concatenate([np.ones((m, 1)), -rng.dirichlet(np.ones(3), size=m)], axis=1)   # a point minus a triangle point
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    inv_mass = np.ones(n)      # all movable: no move exceeds its contact's depth, so the bound never binds
    a, b = x.copy(), x.copy()
    respond(a, inv_mass, _contact_buffer(n, idx, w, d), m, 0.003, np.inf)
    respond(b, inv_mass, _contact_buffer(n, idx, w, d), m, 0.003, 1.0)
    assert np.any(a != x)
    np.testing.assert_array_equal(a, b)


def test_a_held_contact_moves_no_particle_farther_than_its_depth():
    # a point against a triangle two of whose corners are pinned: the third, weight 0.01, is the only
    # one to move; respond moves it 100 depths, bounded (as the held contacts are projected) one
    from stages.sim.cloth_contact.response import respond
    x = np.array([[0.0, 0.001, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    inv_mass = np.array([0.0, 0.0, 0.0, 1.0])
    idx = np.array([[0, 1, 2, 3]])
    w = np.array([[1.0, -0.98, -0.01, -0.01]])
    d = np.array([[0.0, 1.0, 0.0]])
    target = 0.003
    depth = target - 0.001
    a, b, c = x.copy(), x.copy(), x.copy()
    respond(a, inv_mass, _contact_buffer(4, idx, w, d), 1, target, np.inf)
    respond(b, inv_mass, _contact_buffer(4, idx, w, d), 1, target, 1.0)
    respond(c, inv_mass, _contact_buffer(4, idx, w, d), 1, target)     # a call's bound: 3 depths
    assert np.linalg.norm(a[3] - x[3]) > 50 * depth
    assert np.linalg.norm(b[3] - x[3]) == pytest.approx(depth)
    assert np.linalg.norm(c[3] - x[3]) == pytest.approx(3 * depth)
    np.testing.assert_array_equal(b[:3], x[:3])
