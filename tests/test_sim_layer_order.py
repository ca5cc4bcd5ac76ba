"""The simulation's cloth phase sorts layered garments only in its settling frames; from frame 1 on
each pair keeps its side (stages.sim.cloth_contact.phase.ClothPhase): forcing the layers' side then pushed
a single vertex through the other garment where part of one had gone round the other."""
from __future__ import annotations

import numpy as np

from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.phase import ClothPhase
from stages.sim.cloth_contact.bench import grid_sheet

H = 0.003


def inner_flap_over_outer(dip=0.0015):
    """The outer garment (layer 1) a flat sheet at y = 0 (outward +y); the inner garment (layer 0) a
    smaller sheet lying on the wrong side, 12 mm above it, with its middle vertex dipping to `dip`
    above it: no crossing, an inner flap gone round the outer garment."""
    xo, to = grid_sheet(9, 9, 0.16, 0.16)
    xi, ti = grid_sheet(7, 7, 0.1, 0.1, (0.03, 0.012, 0.03))
    v = xo.shape[0] + 3 * 7 + 3
    x = np.concatenate([xo, xi])
    x[v, 1] = dip
    t = np.concatenate([to, ti + xo.shape[0]]).astype(np.int32)
    return x, t, [0, xo.shape[0], x.shape[0]], v


def one_call(tup, xs, xe):
    x = xe.copy()
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    _, _, cinv, topo, tree, work, prm, _, _, _ = tup
    CK.collide_cloth(xs, x, cinv, topo, tree, work, prm, counters)
    return x, counters


def test_running_frames_keep_each_pair_on_its_side():
    x, t, off, v = inner_flap_over_outer()
    # the outer garment is layer 1 (listed first), the inner layer 0; y is outward (no body given);
    # the settling depth = the thickness: `first` is then the rule every frame used to apply
    phase = ClothPhase(x, t, off, np.ones(len(x)), np.array([1, 0]), None, H, 1, H)
    xe = x.copy()
    xe[v, 1] -= 0.0005                       # the dipping vertex moves 0.5 mm further down
    edges = phase.cc.edges
    every = (np.ones(len(edges), bool), np.ones(len(t), bool))
    assert CK.count_edge_triangle_crossings(x, edges, t, *every) == 0
    settled, _ = one_call(phase.first, x, xe)    # the layers' rule: onto the layers' side
    kept, counters = one_call(phase.rest, x, xe)  # every simulated frame: the side it started on
    assert settled[v, 1] < 0.0                   # pushed through the outer sheet alone ...
    assert CK.count_edge_triangle_crossings(settled, edges, t, *every) > 0   # ... its edges cross it
    near = np.linalg.norm(kept[: off[1], ::2] - kept[v, ::2], axis=1) < 0.03
    assert kept[v, 1] > kept[: off[1]][near, 1].max() + 0.5 * H   # kept above the outer sheet
    assert CK.count_edge_triangle_crossings(kept, edges, t, *every) == 0
    assert counters[CK.N_LEFT] == 0 and counters[CK.N_REVERTED] == 0
    # the layers are still reported (and used by the settling tuple)
    assert phase.cc.garment_layer.tolist() == [1, 0]
