"""Data contracts of the simulation stage (paper A §1, §3.2-3.3).

Frames: the simulation runs in the *relative frame* (world minus the root translation, see
stages/rig/types.py); results are stored in WORLD (root translation re-applied).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from stages.checks import ContractError, check_array


HULL_METHODS = ("ray", "brute_ray", "nearest_plane")
REFERENCE_RATE = 300.0        # correction rounds / s at which stretch_stiffness and bend_stiffness are stated
REFERENCE_STEP = 1.0 / 30.0   # s: damping is the share of the velocity lost over this time


@dataclass(frozen=True)
class SimParams:
    """Simulation parameters.

    Defaults are "small steps" (Macklin et al. 2019): 20 steps of two correction rounds per
    frame, with tethers; `SimParams.preset("paper")` is the paper's 1 step x 3 rounds, no tethers.
    Stiffness and damping are stated per unit of time, so that they mean the same at any sub-step
    and round count (frequency-scaled as in NvCloth): see `round_stiffness` and `step_damping`.

    dt: frame time, s (the motion's frame spacing). substeps: steps per frame (step h = dt / substeps);
        collider poses are interpolated between frames (slerp + lerp) at each sub-step.
    iterations: rounds of spring position correction per step (paper: 3).
    gravity: (3,) m/s^2. damping: fraction of the Verlet velocity removed over REFERENCE_STEP (1/30 s),
        [0, 1); a step of length h removes 1 - (1 - damping)^(h / REFERENCE_STEP).
    wind: (3,) air velocity, m/s, world. air_density: kg/m^3. drag, lift: aerodynamic coefficients
        of the per-triangle model (0 disables the term).
    aero_interval: s, the aerodynamic forces are computed once every `aero_steps()` steps, the
        largest divisor of substeps with a span of at most this (0: every step), and held over
        them (their explicit-drag cap over the span); stated in time, so that the forces are sampled
        alike at any sub-step count. Default 1/30 s: once per frame at the defaults, as the paper's
        one step a frame does (the paper preset is unchanged: its step is the span). They were a
        quarter of the drape's sub-step (docs/decisions.md, "Simulation step").
    friction: Coulomb coefficient, [0, 10]: at a contact the tangential travel relative to the
        collider over the step is reduced by up to friction x the push's normal depth (all of it when
        shorter: static friction). Consistent with stages.obstacles.
    inertia_scale: [0, 1]. 0 = the paper's relative simulation (the cloth does not feel the root
        translation), 1 = plain world-space simulation (see simulate.py for the formula).
    stretch_stiffness, bend_stiffness: share of each spring correction applied per round at
        REFERENCE_RATE (300) rounds per second, [0, 1] (paper: 1); at r rounds per second a round applies
        1 - (1 - k)^(300 / r) (1 stays 1: fully stiff at any rate). bend_stiffness defaults to 0.2 (the
        paper preset keeps 1): a bend spring joins the far corners of two triangles at their flat
        (pattern) distance, so where the body curves the cloth it pushes them apart along the chord and
        stretches the mesh edges; at 1 it is as stiff as they are. A sewn tube of 5 cm radius (2.5 cm
        edges) left 1 s without gravity sheared into a slanting tube, the edges round it strained
        1.3 % (0.2: 0.06 %, tests/test_sim_bending.py); on the real characters the mean strain over
        the frames fell from 3.9-5.4 % to 1.9-3.3 % (docs/decisions.md, "Simulation step").
    tethers: long-range attachments (not in the paper): a free particle of a garment with attached or
        pinned particles is kept within its rest distance along the mesh of the nearest one. Without
        them 3 correction rounds let hanging cloth stretch by up to several times its length.
    thickness: m, extra margin around every collider (colliders are already inflated by delta).
    hull_response: 'ray' (paper: OBB, planar-mesh point location, map-volume ray cast), 'brute_ray'
        (the same response by testing every face plane and every face: an independent check of the
        paper's path; compare speeds with `python -m pipeline bench maps`) or 'nearest_plane' (push to the nearest face plane).
    collision_passes: after a push, the particle is re-checked against the other colliders (those
        whose bounding sphere holds it) until one full round sees no push, at most this many rounds;
        a push out of one collider into an overlapping one is so resolved. A particle still inside
        after the budget is between overlapping colliders: see `pinch`. One still inside after that
        (round-off) is counted in penetrations_colliders.
    pinch: cloth pressed between the colliders of two joints (an arm lowered onto the torso, a hand on
        the hip, a knee on the other thigh). 'midpoint' (default): a particle still inside after the
        budget, pressed from opposite sides by two joints' colliders, is left halfway through the
        last push, in the middle of their overlap (counted in SimResult.pinched); otherwise, as
        'escape', moved to a point outside the union of the colliders (the shortest of a few escape
        directions, stages.sim.body_escape.escape_union). 'escape' everywhere: issue 6's rule, kept
        by the paper preset (its figures unchanged); escaping a pinch drags the cloth around the arm
        (BVH walk, T-shirt tucked in the shorts, cloth collision on: p99 strain 61.8 / 104.8 % at the
        last frame; 'midpoint': 33.1 / 30.6 %). 'limb': where the collider of a deeper joint that is
        not the other's parent or child (the limb) overlaps another (the body), the body's collider
        does not push cloth the limb holds or would hold: a particle in both goes midway between
        their two exits, one the body's push would put into the limb halfway out, at once, whichever
        collider is visited first (stages.sim.body_collide._outranked); equal depths as 'midpoint'.
        Against 'midpoint', worst p99 strain after the blend-in: cesium_skirt 127 -> 64 %, bvh_walk
        T-shirt 129 -> 36 %, cesium_outfit trousers 53 -> 35 %; but particles inside the true body
        0.12-0.26 -> 0.8-2.2 % (the overlap's middle is the middle between the skins only where both
        colliders stand the same distance off them): an option, not the default.
    entry_side: a particle that a collider's map would push out through the far side from where it
        came (a thin limb pressing cloth onto the body takes it past the limb's middle in one step)
        leaves by the side it came in instead (stages.sim.body_collide._entry_side). Off by default
        (the paper's map response everywhere): measured on the shipped scenes it did not lower the
        strain (BVH walk T-shirt mean p99 after the blend 43 -> 50 %, CesiumMan 25 -> 25 %).
    face_contact: the colliders also push the cloth's triangles, not only its particles
        (stages.sim.face_collide, after the particles' collisions of every step): each triangle is
        sampled at its centre and its edges' midpoints, and a sample that entered one collider in the
        step (not one it was inside at the step's start: a limb through the triangle; not where two
        colliders overlap: a pinch, left to `pinch`) moves the triangle's corners so that it lands on
        the collider's push. A limb thinner than the triangles then cannot pass between the
        particles. Off by default: on the real-character scenes it did not move the body edges
        through the cloth or the strain beyond run-to-run differences (free body edges after the
        blend-in, worst frame, without -> with: cesium_skirt 48 -> 36, bvh_walk T-shirt 83 -> 92,
        cesium_outfit trousers 41 -> 48, T-shirt 44 -> 35; worst p99 strain 127 -> 95, 129 -> 136,
        53 -> 68, 74 -> 70 %), and the collisions take 2.5-5 times as long.
    strain_limit: share over the rest length, 0 = off: after every step's collisions, a mesh edge
        longer than (1 + strain_limit) times its rest length is shortened back to it, by inverse mass
        (stages.sim.strain_limit): cloth hooked round a limb is let through it instead of staying
        stretched across it (the next step's collisions push it out on the nearer side). Off by
        default: on the real-character scenes at 0.1 it halves the worst p99 strain after the
        blend-in (cesium_skirt 127 -> 46 %, bvh_walk T-shirt 129 -> 52 %) but leaves 1.4-2.4 % of the
        particles inside the true body at the worst frame (0.1-0.3 % without) and does not lower the
        body edges through the cloth.
    limb_release: share over the rest length, 0 = off: after every frame, the free ends of the mesh
        edges stretched more than this that lie on an arm's or leg's collider stop being pushed by
        that limb until they are outside it again (stages.sim.release; counted in
        SimResult.released): cloth a limb tears lets go of it instead of being held torn.
    floor: m, world height of a floor under the cloth, None = none (the dataclass and both presets;
        the pipeline sets it for worn garments from the character, pipeline.scene_motion.motion_floor).
        After the collisions of every step a free particle under it is put back on it, its mid-surface
        half cloth_thickness above (stages.sim.floor), with `friction` against the ground (which
        moves by the inertia scale's share of the root's travel in the relative frame).
    max_speed: m/s; a particle faster than this (or NaN / inf) stops the run as diverged.
    speed_limit: m/s (relative frame), 0 = none: at the end of every step a free particle's Verlet
        velocity is capped at this (stages.sim.integrate.limit_speed; counted per frame in
        SimResult.speed_limited). The pipeline sets it from the clip (pipeline.scene_motion.motion_speed_limit).
    body_audit: count particles inside the true skinned mesh per frame (generalised winding number).
    cloth_collision: the cloth x cloth phase (garment-garment and self collision, stages.sim.cloth_contact)
        last in every step; garments keep the order of their layers (simulate's `layers`: sorted
        into it before frame 1, then kept, as no pair passes through another).
    cloth_thickness: m > 0, distance kept between cloth layers.
    cloth_contact: how the cloth x cloth phase keeps cloth from passing through cloth: 'swept'
        (default: continuous collision tests of every call's motion, stages.sim.cloth_contact.kernels)
        or 'offset' (one proximity query reused while every particle stays within a bound taken from
        its distance to the nearest feature it is not part of, stages.sim.cloth_contact.offset; slower
        on the shipped scenes, docs/benchmarks.md).
    cloth_contact_every: sub-steps per cloth-contact call (1: every sub-step; k > 1: one call swept
        over k sub-steps, the contacts it finds within two thicknesses projected again in every sub-step
        until the next: stages.sim.step.cloth_phase); the largest divisor of substeps up to it is used
        (contact_steps).
    cloth_layer_depth0: m >= cloth_thickness, how deep garments may interpenetrate at frame 0 and be
        sorted by their layers during the settling frames before frame 1 (afterwards no pair is put
        on the layers' side: each keeps its own, stages.sim.cloth_contact.phase.ClothPhase). Deeper
        is not safer: at 3 cm the sorting found ~5,700 contacts a round in the shipped walk (each
        outer feature against inner triangles up to 3 cm off, pushing it several ways), its rounds
        never converged and the fail-safe undid the sorting (on the skinned balls 200-300 crossing
        edges left; 1.5 cm: none after the first settling frame, 8 times fewer cycles).
    settle_frames: frames of the step at the frame-0 pose, heavily damped (SETTLE_DAMPING), before
        frame 0 is recorded, then the velocity zeroed: a sewn garment hangs under full gravity
        before the motion starts (sewing runs at a tiny gravity; without settling the garment
        dropped ~2 cm at once between frames 0 and 1). Only when every garment is attached to the
        body and there are no obstacles: a free cloth falls from where the scene puts it.
    """

    dt: float = 1.0 / 30.0
    substeps: int = 20
    iterations: int = 2
    gravity: tuple = (0.0, -9.81, 0.0)
    damping: float = 0.01
    wind: tuple = (0.0, 0.0, 0.0)
    air_density: float = 1.2
    drag: float = 0.5
    lift: float = 0.1
    aero_interval: float = 1.0 / 30.0
    friction: float = 0.5
    inertia_scale: float = 0.0
    stretch_stiffness: float = 1.0
    bend_stiffness: float = 0.2
    tethers: bool = True
    thickness: float = 0.0
    hull_response: str = "ray"
    collision_passes: int = 4
    pinch: str = "midpoint"
    entry_side: bool = False
    face_contact: bool = False
    strain_limit: float = 0.0
    limb_release: float = 0.0
    floor: float | None = None
    max_speed: float = 100.0
    speed_limit: float = 0.0
    body_audit: bool = True
    cloth_collision: bool = False
    cloth_thickness: float = 0.003
    cloth_contact: str = "swept"
    cloth_contact_every: int = 1
    cloth_layer_depth0: float = 0.015
    settle_frames: int = 0

    def __post_init__(self):
        o = "SimParams"

        def rng(name, lo, hi, lo_open=False, hi_open=False):
            v = getattr(self, name)
            ok = np.isfinite(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
            if not ok:
                raise ContractError(f"{o}.{name}: expected a value in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}, got {v}")

        rng("dt", 0.0, 10.0, lo_open=True)
        for name in ("substeps", "iterations", "collision_passes"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ContractError(f"{o}.{name}: expected an integer >= 1, got {v!r}")
        for name in ("gravity", "wind"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ContractError(f"{o}.{name}: expected 3 finite numbers, got {getattr(self, name)!r}")
        rng("damping", 0.0, 1.0, hi_open=True)
        rng("air_density", 0.0, 1e3)
        rng("drag", 0.0, 1e3)
        rng("lift", 0.0, 1e3)
        rng("aero_interval", 0.0, 10.0)
        rng("friction", 0.0, 10.0)
        rng("inertia_scale", 0.0, 1.0)
        rng("stretch_stiffness", 0.0, 1.0, lo_open=True)
        rng("bend_stiffness", 0.0, 1.0)
        rng("thickness", 0.0, 1.0)
        if self.floor is not None:
            rng("floor", -1e6, 1e6)
        rng("max_speed", 0.0, 1e6, lo_open=True)
        rng("speed_limit", 0.0, 1e6)
        rng("strain_limit", 0.0, 10.0)
        rng("limb_release", 0.0, 100.0)
        rng("cloth_thickness", 0.0, 0.1, lo_open=True)
        rng("cloth_layer_depth0", self.cloth_thickness, 1.0)
        if not (isinstance(self.settle_frames, (int, np.integer)) and not isinstance(self.settle_frames, (bool, np.bool_))
                and 0 <= self.settle_frames <= 10000):
            raise ContractError(f"{o}.settle_frames: expected an integer in [0, 10000], got {self.settle_frames!r}")
        v = self.cloth_contact_every
        if not (isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) and v >= 1):
            raise ContractError(f"{o}.cloth_contact_every: expected an integer >= 1, got {v!r}")
        if self.cloth_contact not in CLOTH_CONTACT_METHODS:
            raise ContractError(f"{o}.cloth_contact: expected one of {', '.join(CLOTH_CONTACT_METHODS)}, got {self.cloth_contact!r}")
        if self.pinch not in PINCH_RULES:
            raise ContractError(f"{o}.pinch: expected one of {', '.join(PINCH_RULES)}, got {self.pinch!r}")
        if not isinstance(self.cloth_collision, (bool, np.bool_)):
            raise ContractError(f"{o}.cloth_collision: expected a bool, got {self.cloth_collision!r}")
        if not isinstance(self.face_contact, (bool, np.bool_)):
            raise ContractError(f"{o}.face_contact: expected a bool, got {self.face_contact!r}")
        if not isinstance(self.entry_side, (bool, np.bool_)):
            raise ContractError(f"{o}.entry_side: expected a bool, got {self.entry_side!r}")
        if not isinstance(self.tethers, (bool, np.bool_)):
            raise ContractError(f"{o}.tethers: expected a bool, got {self.tethers!r}")
        if self.hull_response not in HULL_METHODS:
            raise ContractError(f"{o}.hull_response: expected one of {', '.join(HULL_METHODS)}, got {self.hull_response!r}")

    @property
    def step(self) -> float:
        """Step length h, s."""
        return self.dt / self.substeps

    @classmethod
    def preset(cls, name: str, **overrides) -> "SimParams":
        """The named preset (PRESETS) with `overrides` (keyword fields) on top."""
        if name not in PRESETS:
            raise ContractError(f"SimParams.preset: unknown preset {name!r}; choose from {', '.join(PRESETS)}")
        return cls(**{**PRESETS[name], **overrides})

    def aero_steps(self) -> int:
        """Steps per aerodynamic force computation: the largest divisor of substeps whose span
        (steps x step) is at most aero_interval (1e-9 relative slack), at least 1."""
        for k in range(self.substeps, 1, -1):
            if self.substeps % k == 0 and k * self.step <= self.aero_interval * (1 + 1e-9):
                return k
        return 1

    def contact_steps(self) -> int:
        """Sub-steps per cloth x cloth call: the largest divisor of substeps up to cloth_contact_every."""
        return max(k for k in range(1, min(self.cloth_contact_every, self.substeps) + 1) if self.substeps % k == 0)

    def round_stiffness(self, k: float) -> float:
        """The share of a correction one round applies for stiffness k stated at REFERENCE_RATE."""
        rate = self.iterations / self.step
        return 1.0 - (1.0 - float(k)) ** (REFERENCE_RATE / rate)

    def step_damping(self) -> float:
        """The share of the velocity one step removes (damping is stated over REFERENCE_STEP); the
        value itself at a step of REFERENCE_STEP (bit for bit: the paper preset's figures)."""
        ratio = self.step / REFERENCE_STEP
        if abs(ratio - 1.0) < 1e-12:
            return float(self.damping)
        return 1.0 - (1.0 - float(self.damping)) ** ratio

    def as_dict(self) -> dict:
        """Plain dict for the recording's static record."""
        d = asdict(self)
        d["gravity"] = list(map(float, self.gravity))
        d["wind"] = list(map(float, self.wind))
        return d


# Named parameter sets. "default": the dataclass defaults with cloth x cloth collision on (a call
# every 5 sub-steps, the contacts held between: garments layered or long enough to fold pass
# through each other and themselves without it) and 10 settling frames before frame 0. "paper": paper A's step (one Verlet step and 3 rounds
# of spring correction per 1/30 s frame, no tethers, no cloth collision), whose figures it reproduces.
PINCH_RULES = ("escape", "midpoint", "limb")    # the index is collide's code (body_collide.PINCH_*)
CLOTH_CONTACT_METHODS = ("offset", "swept")
SETTLE_DAMPING = 0.3     # share of the velocity lost per 1/30 s while a garment settles before frame 0
PRESETS = {
    "default": {"cloth_collision": True, "cloth_contact_every": 5, "settle_frames": 10},
    "paper": {"substeps": 1, "iterations": 3, "tethers": False, "cloth_collision": False, "pinch": "escape",
              "bend_stiffness": 1.0},
}


@dataclass(frozen=True)
class GarmentTrack:
    """One garment's simulated frames.

    name: garment name. triangles: (T, 3) int32 (static).
    positions: (F, N, 3) float32, metres, WORLD frame (root translation re-applied).
    penetrations_colliders: (F,) int32, this garment's particles inside any collider after the
        frame's last step. penetrations_body: (F,) int32, particles inside the skinned mesh but where
        it meets itself (-1 when the audit is off). penetrations_body_overlap: (F,) int32, particles
        inside it where it meets itself (stages.sim.body_audit.inside_where_body_meets_itself: another
        part of the body sunk into the one under the cloth, where no cloth can lie outside both).
    """

    name: str
    triangles: np.ndarray
    positions: np.ndarray
    penetrations_colliders: np.ndarray
    penetrations_body: np.ndarray
    penetrations_body_overlap: np.ndarray | None = None

    def __post_init__(self):
        o = f"GarmentTrack[{self.name!r}]"
        check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        p = check_array(o, "positions", self.positions, (None, None, 3), np.float32)
        check_array(o, "penetrations_colliders", self.penetrations_colliders, (p.shape[0],), np.int32)
        check_array(o, "penetrations_body", self.penetrations_body, (p.shape[0],), np.int32)
        if self.penetrations_body_overlap is None:
            object.__setattr__(self, "penetrations_body_overlap", np.zeros(p.shape[0], np.int32))
        check_array(o, "penetrations_body_overlap", self.penetrations_body_overlap, (p.shape[0],), np.int32)


@dataclass(frozen=True)
class SimResult:
    """The simulation of every garment over the motion's frames.

    garments: one GarmentTrack per garment, in input order.
    times: (F,) float64, s, the motion's frame times.
    penetrations_colliders: (F,) int32, particles (all garments) inside any collider after the
        frame's last step (target 0).
    penetrations_body: (F,) int32, particles inside the true skinned character mesh at the frame
        (generalised winding number >= 0.5) but where it meets itself; -1 when the audit is off.
    penetrations_body_overlap: (F,) int32, particles inside it where it meets itself (see
        GarmentTrack), counted apart.
    corrected: (F,) int32, particles the collision response moved at least once during the frame.
    speed_limited: (F,) int32, particles whose speed SimParams.speed_limit capped during the frame.
    released: (F,) int32, particles SimParams.limb_release let go of a limb at the frame.
    pinched: (F,) int32, particles left in the middle of two joints' colliders pressing on them at
        the frame's last step (SimParams.pinch 'midpoint'; not in penetrations_colliders).
    max_speed: (F,) float64, m/s, the fastest particle at the end of the frame (relative frame).
    step_ms: (F,) float64, wall milliseconds per step in the frame (frame time / substeps; the
        body audit excluded; 0 for frame 0, the initial state).
    timings: total seconds per phase: 'poses' (collider / attachment poses), 'integrate'
        (forces + Verlet + attachments), 'constraints' (springs), 'collisions', 'audit'
        (skinning + winding numbers), 'setup' (particle system, springs, tethers, collider arrays, audit
        tree), 'obstacles', 'total' (whole call).
    steps: number of steps simulated. params: the SimParams used.
    notes: human-readable remarks (e.g. which collision path was used for hulls).
    contacts_obstacles: (F,) int32, obstacle contacts (paper B) summed over the frame's steps; 0
        without obstacles.
    contact_points: per frame, (c, 3) float32 world positions of the particles in contact with an
        obstacle at the frame's last step (empty arrays without obstacles).
    cloth_contact: the cloth x cloth phase's counters summed over the run (ClothPhase.summary();
        empty when params.cloth_collision is off); timings['cloth'] its time.
    """

    garments: tuple
    times: np.ndarray
    penetrations_colliders: np.ndarray
    penetrations_body: np.ndarray
    corrected: np.ndarray
    max_speed: np.ndarray
    step_ms: np.ndarray
    timings: dict
    steps: int
    params: SimParams
    notes: tuple = field(default_factory=tuple)
    contacts_obstacles: np.ndarray | None = None
    contact_points: tuple = ()
    cloth_contact: dict = field(default_factory=dict)
    pinched: np.ndarray | None = None
    speed_limited: np.ndarray | None = None
    penetrations_body_overlap: np.ndarray | None = None
    released: np.ndarray | None = None

    def __post_init__(self):
        o = "SimResult"
        t = check_array(o, "times", self.times, (None,), np.float64)
        f = t.size
        if self.contacts_obstacles is None:
            object.__setattr__(self, "contacts_obstacles", np.zeros(f, np.int32))
        if self.pinched is None:
            object.__setattr__(self, "pinched", np.zeros(f, np.int32))
        if self.speed_limited is None:
            object.__setattr__(self, "speed_limited", np.zeros(f, np.int32))
        if self.penetrations_body_overlap is None:
            object.__setattr__(self, "penetrations_body_overlap", np.zeros(f, np.int32))
        if not self.contact_points:
            object.__setattr__(self, "contact_points", tuple(np.zeros((0, 3), np.float32) for _ in range(f)))
        if len(self.contact_points) != f:
            raise ContractError(f"{o}.contact_points: {len(self.contact_points)} frames, expected {f}")
        for name in ("penetrations_colliders", "penetrations_body", "corrected", "contacts_obstacles", "pinched",
                     "speed_limited", "penetrations_body_overlap"):
            check_array(o, name, getattr(self, name), (f,), np.int32)
        check_array(o, "max_speed", self.max_speed, (f,), np.float64)
        check_array(o, "step_ms", self.step_ms, (f,), np.float64)
        for g in self.garments:
            if g.positions.shape[0] != f:
                raise ContractError(f"{o}.garments[{g.name!r}]: {g.positions.shape[0]} frames, expected {f}")

    def garment(self, name: str) -> GarmentTrack:
        for g in self.garments:
            if g.name == name:
                return g
        raise KeyError(f"no garment {name!r}; garments: {[g.name for g in self.garments]}")

    @property
    def n_frames(self) -> int:
        return int(self.times.size)

    def penetration_summary(self) -> dict:
        """Max / mean per frame and worst frame of both penetration counts, and particle total."""
        out = {"particles": int(sum(g.positions.shape[1] for g in self.garments))}
        for key in ("colliders", "body"):
            a = getattr(self, f"penetrations_{key}")
            out[key] = {"max": int(a.max()) if a.size else 0, "mean": float(a.mean()) if a.size else 0.0,
                        "worst_frame": int(np.argmax(a)) if a.size else 0}
        return out


class SimulationDiverged(RuntimeError):
    """The cloth blew up (NaN / inf or a particle faster than SimParams.max_speed).

    frame: the frame index where it was detected; particles: the offending particle indices
    (global, all garments concatenated in input order) with their garment names; partial: the
    SimResult of the frames before it (None if frame 0).
    """

    def __init__(self, frame: int, particles, garment_names, speed: float, partial=None):
        self.frame = int(frame)
        self.particles = np.asarray(particles)
        self.garment_names = tuple(garment_names)
        self.partial = partial
        shown = ", ".join(f"{g}#{i}" for g, i in list(zip(self.garment_names, self.particles))[:8])
        more = f" (+{self.particles.size - 8} more)" if self.particles.size > 8 else ""
        super().__init__(f"simulation diverged at frame {self.frame}: {self.particles.size} particle(s) "
                         f"non-finite or faster than the limit (max speed {speed:.3g} m/s): {shown}{more}")
