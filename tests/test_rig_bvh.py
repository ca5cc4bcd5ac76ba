"""BVH parser, clip and character: hand-made files checked against hand-built rotation matrices."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.errors import InputError
from stages.rig.bvh import bvh_clip, parse_bvh
from stages.rig.transforms import forward_kinematics, trs_to_matrix
from tests.bvh_humanoid import HUMANOID, bind_positions, edge_ratios, humanoid_bvh, skin_gap, unit


# ------------------------------------------------------------- independent reference (no scipy)


def axis_matrix(axis: str, deg: float) -> np.ndarray:
    """Right-handed rotation about one axis, written out by hand."""
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    if axis == "X":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "Y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def reference_world(parents, offsets, channels, values) -> np.ndarray:
    """World positions (J, 3) from explicit 3x3 products: listed-order intrinsic rotations,
    position channels replacing the offset component-wise."""
    world_r, world_t = [], []
    col = 0
    for j, p in enumerate(parents):
        t = np.array(offsets[j], dtype=float)
        r = np.eye(3)
        for c in channels[j]:
            v = values[col]
            col += 1
            if c.endswith("position"):
                t["XYZ".index(c[0])] = v
            else:
                r = r @ axis_matrix(c[0], v)
        if p < 0:
            world_r.append(r)
            world_t.append(t)
        else:
            world_r.append(world_r[p] @ r)
            world_t.append(world_t[p] + world_r[p] @ t)
    return np.array(world_t)


def clip_world(clip, parents, key=0) -> np.ndarray:
    local = trs_to_matrix(clip.translations[key], clip.rotations[key], clip.scales[key])
    return forward_kinematics(parents, local)[:, :3, 3]


def write(tmp_path, text: str, name: str = "t.bvh"):
    path = tmp_path / name
    path.write_text(text)
    return path


def bvh_text(spec, frames, frame_time=0.05, end_offset=(0.0, 0.0, 0.5)) -> str:
    """A chain ROOT J0 -> J1 -> ... from spec = [(offset, channels)], with an End Site at the tip."""
    out = ["HIERARCHY"]
    for k, (off, chans) in enumerate(spec):
        out.append(("ROOT" if k == 0 else "JOINT") + f" J{k}")
        out.append("{")
        out.append("OFFSET " + " ".join(repr(float(x)) for x in off))
        out.append(f"CHANNELS {len(chans)} " + " ".join(chans))
    out += ["End Site", "{", "OFFSET " + " ".join(repr(float(x)) for x in end_offset), "}"]
    out += ["}"] * len(spec)
    out += ["MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time}"]
    out += [" ".join(repr(float(v)) for v in row) for row in frames]
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------- hand-made channel orders

UNUSUAL = """HIERARCHY
ROOT Hips
{
  OFFSET 1.0 2.0 3.0
  CHANNELS 6 Zposition Xposition Yposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 1 0
    CHANNELS 3 Yrotation Xrotation Zrotation
    JOINT Arm
    {
      OFFSET 0.0 0.0 1.0
      CHANNELS 2 Yrotation Xrotation
      JOINT Hand
      {
        OFFSET 1 0 0
        CHANNELS 4 Xrotation Yposition Zrotation Yrotation
        End Site
        {
          OFFSET 0.5 0 0
        }
      }
    }
  }
  JOINT Leg
  {
    OFFSET 0.2 -0.5 0
    End Site
    {
      OFFSET 0 -0.4 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0.3 -0.2 0.9   10 -35 70    20 45 -15   -60 30   5 0.25 80 -25
1   2    3     0  0   0     0  0  0     0 0      0 0 0 0
"""
UNUSUAL_CHANNELS = [
    ("Zposition", "Xposition", "Yposition", "Zrotation", "Xrotation", "Yrotation"),
    ("Yrotation", "Xrotation", "Zrotation"),
    ("Yrotation", "Xrotation"),
    ("Xrotation", "Yposition", "Zrotation", "Yrotation"),
    (),
    (),
    (),
]
UNUSUAL_OFFSETS = [(1, 2, 3), (0, 1, 0), (0, 0, 1), (1, 0, 0), (0.5, 0, 0), (0.2, -0.5, 0), (0, -0.4, 0)]
UNUSUAL_PARENTS = [-1, 0, 1, 2, 3, 0, 5]


def test_unusual_channel_orders_match_hand_built_matrices(tmp_path):
    data = parse_bvh(write(tmp_path, UNUSUAL))
    assert data.joint_names == ("Hips", "Spine", "Arm", "Hand", "Hand_end", "Leg", "Leg_end")
    assert data.parents.tolist() == UNUSUAL_PARENTS
    assert data.channels == tuple(UNUSUAL_CHANNELS)
    assert data.end_site.tolist() == [False, False, False, False, True, False, True]
    assert data.channel_start.tolist() == [0, 6, 9, 11, 15, 15, 15]
    assert data.frames.shape == (2, 15) and data.frame_time == pytest.approx(0.0333333)

    clip = bvh_clip(data, name="unusual")
    assert clip.times.tolist() == pytest.approx([0.0, 0.0333333])
    assert clip.translations.shape == (2, 7, 3)
    for key in range(2):
        expected = reference_world(UNUSUAL_PARENTS, UNUSUAL_OFFSETS, UNUSUAL_CHANNELS, data.frames[key])
        np.testing.assert_allclose(clip_world(clip, data.parents, key), expected, atol=1e-12)


def test_position_channels_replace_the_offset(tmp_path):
    clip = bvh_clip(parse_bvh(write(tmp_path, UNUSUAL)))
    # Root: Z X Y position columns -> translation (x, y, z) = (-0.2, 0.9, 0.3), offset (1, 2, 3) ignored.
    np.testing.assert_allclose(clip.translations[0, 0], [-0.2, 0.9, 0.3])
    # Hand: only Yposition -> y replaced by 0.25, x and z kept from the offset (1, 0, 0).
    np.testing.assert_allclose(clip.translations[0, 3], [1.0, 0.25, 0.0])
    # Frame 1: all rotations zero, root at (2, 3, 1): world = root position + summed offsets.
    world = clip_world(clip, np.array(UNUSUAL_PARENTS), key=1)
    np.testing.assert_allclose(world[4], [2 + 0 + 0 + 1 + 0.5, 3 + 1 + 0 + 0, 1 + 0 + 1 + 0])


def test_rotation_order_is_listed_order_intrinsic(tmp_path):
    # Zrotation 90 then Xrotation 90, child offset (0, 0, 1):
    # Rz(90) @ Rx(90) @ (0,0,1) = Rz(90) @ (0,-1,0) = (1, 0, 0). The reverse order would give (0,-1,0).
    text = bvh_text([((0, 0, 0), ("Zrotation", "Xrotation")), ((0, 0, 1), ())], [[90, 90]])
    clip = bvh_clip(parse_bvh(write(tmp_path, text)))
    world = clip_world(clip, np.array([-1, 0, 1]))
    np.testing.assert_allclose(world[1], [1, 0, 0], atol=1e-12)
    text = bvh_text([((0, 0, 0), ("Xrotation", "Zrotation")), ((0, 0, 1), ())], [[90, 90]])
    clip = bvh_clip(parse_bvh(write(tmp_path, text)))
    np.testing.assert_allclose(clip_world(clip, np.array([-1, 0, 1]))[1], [0, -1, 0], atol=1e-12)


AXES = ("Xrotation", "Yrotation", "Zrotation")
POSITIONS = ("Xposition", "Yposition", "Zposition")


@st.composite
def chains(draw):
    n = draw(st.integers(1, 4))
    spec = []
    for _ in range(n):
        chans = draw(st.lists(st.sampled_from(AXES + POSITIONS), unique=True, max_size=6))
        off = draw(st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3))
        spec.append((off, tuple(chans)))
    n_ch = sum(len(c) for _, c in spec)
    frame = draw(st.lists(st.floats(-180, 180, allow_nan=False), min_size=n_ch, max_size=n_ch))
    return spec, frame


@settings(max_examples=40, deadline=None)
@given(chains())
def test_random_channel_layouts_match_reference(tmp_path_factory, chain):
    spec, frame = chain
    path = write(tmp_path_factory.mktemp("bvh"), bvh_text(spec, [frame]))
    data = parse_bvh(path)
    clip = bvh_clip(data)
    parents = list(range(-1, len(spec)))
    offsets = [s[0] for s in spec] + [(0, 0, 0.5)]
    channels = [s[1] for s in spec] + [()]
    expected = reference_world(parents, offsets, channels, np.array(frame))
    np.testing.assert_allclose(clip_world(clip, data.parents), expected, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(clip.rotations, axis=-1), 1.0, atol=1e-12)


def test_any_whitespace_layout_of_frames(tmp_path):
    one_per_line = parse_bvh(write(tmp_path, UNUSUAL, "a.bvh"))
    head, _, _ = UNUSUAL.partition("0.3 -0.2")
    values = [v for row in one_per_line.frames for v in row]
    scattered = head + "\n".join(" \t ".join(repr(float(v)) for v in values[i:i + 4]) for i in range(0, len(values), 4)) + "\n\n"
    again = parse_bvh(write(tmp_path, scattered, "b.bvh"))
    np.testing.assert_array_equal(again.frames, one_per_line.frames)


def test_scale_multiplies_offsets_and_positions_not_angles(tmp_path):
    path = write(tmp_path, UNUSUAL)
    a, b = parse_bvh(path), parse_bvh(path, scale=0.01)
    np.testing.assert_allclose(b.offsets, a.offsets * 0.01)
    pos = [0, 1, 2, 12]  # Zposition Xposition Yposition of the root, Yposition of Hand
    rot = [c for c in range(15) if c not in pos]
    np.testing.assert_allclose(b.frames[:, pos], a.frames[:, pos] * 0.01)
    np.testing.assert_array_equal(b.frames[:, rot], a.frames[:, rot])


def test_clip_frame_selection(tmp_path):
    data = parse_bvh(write(tmp_path, UNUSUAL))
    full = bvh_clip(data)
    tail = bvh_clip(data, name="tail", frames=slice(1, None))
    assert tail.name == "tail" and tail.times.tolist() == [0.0]
    np.testing.assert_array_equal(tail.rotations[0], full.rotations[1])
    with pytest.raises(ValueError):
        bvh_clip(data, frames=[1, 0])


def test_end_site_names_stay_unique(tmp_path):
    text = UNUSUAL.replace("JOINT Leg", "JOINT Hand_end")
    data = parse_bvh(write(tmp_path, text))
    assert data.joint_names == ("Hips", "Spine", "Arm", "Hand", "Hand_end2", "Hand_end", "Hand_end_end")


# ---------------------------------------------------------------------------------- bad files


def _replace(old, new, count=1):
    assert old in UNUSUAL
    return UNUSUAL.replace(old, new, count)


BAD = {
    "empty": ("", "empty file"),
    "blank": ("  \n\n\t\n", "empty file"),
    "short frame line": (_replace("5 0.25 80 -25", "5 0.25 80"), "line 37: frame 0 has 14 values, expected 15"),
    "long frame line": (_replace("0 0 0 0\n", "0 0 0 0 7\n"), "line 38: frame 1 has 16 values, expected 15"),
    "missing frames": (_replace("Frames: 2", "Frames: 3"), "fewer frames than declared: Frames: 3"),
    "extra frames": (UNUSUAL + "1 2 3 0 0 0 0 0 0 0 0 0 0 0 0\n", "line 39: more frame data than declared"),
    "missing MOTION": (UNUSUAL.split("MOTION")[0], "no MOTION section"),
    "bad number in frames": (_replace("-60 30", "-60 3O"), "line 37: bad number '3O' in MOTION data"),
    "nan in frames": (_replace("-60 30", "-60 nan"), "line 37: non-finite number 'nan'"),
    "bad number in offset": (_replace("OFFSET 0.2 -0.5 0", "OFFSET 0.2 -0.5 zero"), "line 27: bad number 'zero' in OFFSET"),
    "missing close brace": (_replace("    }\n  }\n  JOINT Leg", "    }\n  JOINT Leg"), "line 33: unbalanced braces: ROOT Hips opened at line 2 is not closed"),
    "extra close brace": (_replace("}\nMOTION", "}\n}\nMOTION"), "line 34: unbalanced braces: '}' without a matching '{'"),
    "unknown channel": (_replace("Yrotation Xrotation\n", "Yrotation Wrotation\n"), "line 13: unknown channel 'Wrotation'"),
    "too few channel names": (_replace("CHANNELS 2 Yrotation", "CHANNELS 3 Yrotation"), "line 13: CHANNELS 3 lists only 2 channel names"),
    "duplicate channel": (_replace("Yrotation Xrotation\n", "Yrotation Yrotation\n"), "line 13: channel Yrotation listed twice"),
    "no frame time": (_replace("Frame Time: 0.0333333\n", ""), "line 36: expected 'Frame Time: <number>'"),
    "zero frame time": (_replace("Frame Time: 0.0333333", "Frame Time: 0"), "line 36: Frame Time must be positive"),
    "zero frames": (_replace("Frames: 2", "Frames: 0"), "line 35: Frames: 0"),
    "second root": (UNUSUAL.replace("MOTION", "ROOT Other\n{\nOFFSET 0 0 0\n}\nMOTION"), "line 34: a second ROOT"),
    "no hierarchy keyword": (UNUSUAL.replace("HIERARCHY\n", ""), "line 1: expected HIERARCHY"),
    "duplicate joint": (_replace("JOINT Leg", "JOINT Arm"), "joint name 'Arm' is used twice"),
    "no offset": (_replace("    OFFSET 0.2 -0.5 0\n", ""), "line 25: JOINT Leg has no OFFSET"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_file_raises_one_input_error(tmp_path, case):
    text, problem = BAD[case]
    path = write(tmp_path, text, "bad.bvh")
    with pytest.raises(InputError) as err:
        parse_bvh(path)
    assert err.value.source == str(path)
    assert problem in err.value.problem, err.value.problem
    assert str(err.value).startswith(str(path))


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="BVH file not found"):
        parse_bvh(tmp_path / "nope.bvh")


# ---------------------------------------------------------------------------- real CMU capture


@pytest.fixture(scope="module")
def cmu(assets_dir):
    return parse_bvh(assets_dir / "cmu_131_01_walk.bvh")


@pytest.mark.assets
def test_cmu_file_numbers(cmu):
    assert cmu.n_frames == 995
    assert cmu.frame_time == pytest.approx(1 / 120, rel=1e-4)
    assert int((~cmu.end_site).sum()) == 31  # real joints
    assert int(cmu.end_site.sum()) == 7  # toes, head, fingers and thumbs
    assert cmu.n_joints == 38
    assert cmu.n_channels == 6 + 30 * 3
    assert cmu.joint_names[0] == "Hips"
    assert cmu.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    clip = bvh_clip(cmu)
    assert clip.translations.shape == (995, 38, 3)
    assert clip.duration == pytest.approx(994 * cmu.frame_time)
    # Metres and Y up: the head's end site is 1.3-1.6 m above the lowest joint at frame 0.
    world = clip_world(clip, cmu.parents)
    height = world[cmu.joint_names.index("Head_end"), 1] - world[:, 1].min()
    assert 1.3 < height < 1.6


# ------------------------------------------------------------------------------------- character

FIGURE = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
  JOINT Spine
  {
    OFFSET 0 0.3 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0.4 0
    }
  }
  JOINT LeftLeg
  {
    OFFSET 0.1 -0.05 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 0 -0.8 0
    }
  }
  JOINT RightLeg
  {
    OFFSET -0.1 -0.05 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 0 -0.8 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.1
2.0 0.95 -1.0   30 5 0   10 0 0   -20 0 5   15 0 -5
2.1 0.90 -0.8   35 0 0   0 0 0   0 0 0   0 0 0
2.2 0.97 -0.6   40 0 0   0 0 0   -40 0 0   30 0 0
"""


def skinned_frames(character, times):
    from stages.rig.skinning import sample_motion, skin

    motion = sample_motion(character, 0, times)
    return skin(character, motion) + motion.root_translation[:, None, :]


def test_character_frame_zero_is_the_bind_pose_on_the_floor(tmp_path):
    from stages.rig.bvh_character import load_bvh_character

    path = write(tmp_path, FIGURE, "figure.bvh")
    ch = load_bvh_character(path, bind_pose="frame0")
    assert ch.name == "figure" and ch.source == str(path) and ch.root_joint == 0
    assert ch.joint_names == ("Hips", "Spine", "Spine_end", "LeftLeg", "LeftLeg_end", "RightLeg", "RightLeg_end")
    assert ch.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-12)
    clip = ch.clip(0)
    assert clip.name == "figure" and clip.times.tolist() == pytest.approx([0.0, 0.1, 0.2])
    # The clip's root is moved by one constant: over the origin at frame 0, key-to-key motion kept.
    raw = bvh_clip(parse_bvh(path))
    shift = clip.translations[:, 0] - raw.translations[:, 0]
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-12)
    np.testing.assert_allclose(clip.translations[0, 0, [0, 2]], 0.0, atol=1e-12)
    np.testing.assert_array_equal(clip.translations[:, 1:], raw.translations[:, 1:])
    np.testing.assert_array_equal(clip.rotations, raw.rotations)
    # Frame 0 (the bind frame) reproduces the bind mesh exactly.
    frames = skinned_frames(ch, clip.times)
    np.testing.assert_allclose(frames[0], ch.vertices, atol=1e-9)
    # The bind skeleton is frame 0's pose: world joints match FK of the clip's first key.
    bind = np.linalg.inv(ch.inverse_bind)
    np.testing.assert_allclose(bind, forward_kinematics(ch.parents, ch.rest_local), atol=1e-12)
    first = forward_kinematics(ch.parents, trs_to_matrix(clip.translations[0], clip.rotations[0]))
    np.testing.assert_allclose(bind, first, atol=1e-12)


def test_character_rest_pose_bind(tmp_path):
    from stages.rig.bvh_character import load_bvh_character

    path = write(tmp_path, FIGURE, "figure.bvh")
    ch = load_bvh_character(path, bind_pose="rest")
    data = parse_bvh(path)
    # Rest pose: no rotation, offsets only (root lifted onto the floor).
    np.testing.assert_allclose(ch.rest_local[:, :3, :3], np.broadcast_to(np.eye(3), (7, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(ch.rest_local[1:, :3, 3], data.offsets[1:], atol=1e-12)
    assert ch.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-12)
    # Frame 0 differs from the bind pose, but it still stands on the floor over the origin.
    v0 = skinned_frames(ch, [0.0])[0]
    assert v0[:, 1].min() == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(ch.clip(0).translations[0, 0, [0, 2]], 0.0, atol=1e-12)


def test_armless_figure_falls_back_to_frame_zero_with_a_warning(tmp_path):
    from stages.rig.bvh_character import load_bvh_character

    path = write(tmp_path, FIGURE, "figure.bvh")
    with pytest.warns(UserWarning, match="no neutral bind pose, no humanoid shape found.*frame 0 instead"):
        ch = load_bvh_character(path)
    old = load_bvh_character(path, bind_pose="frame0")
    np.testing.assert_array_equal(ch.vertices, old.vertices)
    np.testing.assert_array_equal(ch.inverse_bind, old.inverse_bind)


def test_bind_options_are_checked(tmp_path):
    from stages.rig.bvh_character import load_bvh_character

    path = write(tmp_path, FIGURE, "figure.bvh")
    with pytest.raises(ValueError, match="bind_pose must be one of neutral, frame0, rest, got 'tpose'"):
        load_bvh_character(path, bind_pose="tpose")
    with pytest.raises(ValueError, match="bind_pose='rest'"):
        load_bvh_character(path, bind_frame=None)  # the old spelling of the rest pose
    with pytest.raises(ValueError, match=r"bind_frame 3 out of range \[0, 3\)"):
        load_bvh_character(path, bind_pose="frame0", bind_frame=3)
    later = load_bvh_character(path, bind_pose="frame0", bind_frame=2)
    frames = skinned_frames(later, later.clip(0).times)
    np.testing.assert_allclose(frames[2] - frames[2].min(axis=0), later.vertices - later.vertices.min(axis=0), atol=1e-9)


@pytest.fixture(scope="module")
def cmu_character(assets_dir):
    from stages.rig.bvh_character import load_bvh_character

    return load_bvh_character(assets_dir / "cmu_131_01_walk.bvh")


@pytest.mark.assets
def test_cmu_character_skin(cmu_character):
    import trimesh

    ch = cmu_character
    assert ch.n_joints == 38 and len(ch.clips) == 1 and ch.clip(0).times.size == 995
    mesh = trimesh.Trimesh(ch.vertices, ch.triangles, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    np.testing.assert_allclose(ch.skin_weights.sum(axis=1), 1.0, atol=1e-9)
    assert ch.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-12)
    height = ch.vertices[:, 1].max()
    assert 1.35 < height < 1.6  # CMU subject 131, metres
    # End sites carry no skin weight (they only give the leaf bones their length).
    end = [j for j, n in enumerate(ch.joint_names) if n.endswith("_end")]
    assert len(end) == 7
    assert not np.any(np.isin(ch.skin_joints, end) & (ch.skin_weights > 0))
    # Frame 0 (hands on hips, not the bind pose) stands on the floor with its root over the origin.
    frames = skinned_frames(ch, [0.0, 5.0])
    assert frames[0][:, 1].min() == pytest.approx(0.0, abs=1e-9)
    root0 = forward_kinematics(ch.parents, trs_to_matrix(ch.clip(0).translations[0], ch.clip(0).rotations[0]))[0, :3, 3]
    np.testing.assert_allclose(root0[[0, 2]], 0.0, atol=1e-12)
    # 5 s in, the subject is walking along +Z, still on the floor (within 3 cm of mocap noise).
    assert frames[1][:, 2].mean() - frames[0][:, 2].mean() > 1.0
    assert abs(frames[1][:, 1].min()) < 0.03


def test_crlf_bom_and_compact_header(tmp_path):
    text = "\ufeff" + UNUSUAL.replace("Frames: 2", "FRAMES:2").replace("Frame Time: ", "Frame Time:\t")
    path = tmp_path / "crlf.bvh"
    path.write_bytes(text.replace("\n", "\r\n").encode("utf-8"))
    a, b = parse_bvh(path), parse_bvh(write(tmp_path, UNUSUAL))
    assert a.joint_names == b.joint_names
    np.testing.assert_array_equal(a.frames, b.frames)
    assert a.frame_time == b.frame_time


# ------------------------------------------------------------------------ neutral bind pose

@pytest.mark.parametrize("variant", ["clavicles", "no clavicles", "anonymous", "floor root"])
def test_neutral_bind_pose_of_a_humanoid(tmp_path, variant):
    """Limbs found by shape (also with meaningless names), re-posed: legs down and slightly apart,
    arms 40 degrees from the body with straight elbows, spine upright, facing as frame 0."""
    from stages.rig.bvh_character import load_bvh_character
    from stages.rig.neutral_pose import ARM_ANGLE_DEG, LEG_SPLAY_DEG

    rename = {n: f"j{k}" for k, (n, _, _) in enumerate(HUMANOID)} if variant == "anonymous" else None
    path = write(tmp_path, humanoid_bvh(rename, clavicles=variant != "no clavicles", floor_root=variant == "floor root"), "h.bvh")
    ch = load_bvh_character(path)
    back = {v: k for k, v in (rename or {}).items()}
    back.update({v + "_end": k + "_end" for k, v in (rename or {}).items()})
    p = {back.get(n, n): x for n, x in bind_positions(ch).items()}
    np.testing.assert_allclose(ch.inverse_bind, np.linalg.inv(forward_kinematics(ch.parents, ch.rest_local)), atol=1e-12)
    up = np.array([0.0, 1.0, 0.0])
    assert np.dot(unit(p["Head"] - p["Spine"]), up) > 0.9999
    # the left-right axis of frame 0 (turned 20 degrees about Y) is the bind pose's
    first = forward_kinematics(ch.parents, trs_to_matrix(ch.clip(0).translations[0], ch.clip(0).rotations[0]))
    f0 = {back.get(n, n): first[j, :3, 3] for j, n in enumerate(ch.joint_names)}
    lateral = unit(p["LeftUpLeg"] - p["RightUpLeg"])
    np.testing.assert_allclose(lateral, unit(f0["LeftUpLeg"] - f0["RightUpLeg"]), atol=1e-9)
    for side, s in (("Left", 1), ("Right", -1)):
        for a, b in ((f"{side}UpLeg", f"{side}Leg"), (f"{side}Leg", f"{side}Foot")):
            d = unit(p[b] - p[a])
            assert np.degrees(np.arccos(-d[1])) == pytest.approx(LEG_SPLAY_DEG, abs=1e-6)
            assert s * np.dot(d, lateral) > 0  # outward
        assert abs(p[f"{side}Toe"][1] - p[f"{side}Foot"][1]) == pytest.approx(0.05, abs=1e-9)  # foot flat
        for a, b in ((f"{side}Arm", f"{side}ForeArm"), (f"{side}ForeArm", f"{side}Hand"), (f"{side}Hand", f"{side}Hand_end")):
            d = unit(p[b] - p[a])
            assert np.degrees(np.arccos(-d[1])) == pytest.approx(ARM_ANGLE_DEG, abs=1e-6)
            assert s * np.dot(d, lateral) > 0
        if variant != "no clavicles":  # the clavicle keeps its rest direction: level, sideways
            assert abs(p[f"{side}Arm"][1] - p[f"{side}Shoulder"][1]) < 1e-9
        assert skin_gap(ch, f"{side}Hand" if rename is None else rename[f"{side}Hand"],
                        [rename.get(n, n) if rename else n for n in ("Hips", "LeftUpLeg", "RightUpLeg")]) > 0.10


def test_neutral_bind_does_not_web_hands_to_hips(tmp_path):
    """Frame 0 has the hands on the hips: bound there, the skin joins them and the web stretches
    as the arms swing; bound in the neutral pose no edge passes 4x the median at any frame."""
    from stages.rig.bvh_character import load_bvh_character

    path = write(tmp_path, humanoid_bvh(), "h.bvh")
    old = load_bvh_character(path, bind_pose="frame0")
    assert skin_gap(old, "LeftHand", ("Hips", "LeftUpLeg")) < 0.03  # touching at frame 0
    assert edge_ratios(old).max() > 6.0
    ch = load_bvh_character(path)
    assert edge_ratios(ch).max() < 4.0
    frames = skinned_frames(ch, ch.clip(0).times)  # placement: frame 0 on the floor, over the origin
    assert frames[0][:, 1].min() == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(ch.clip(0).translations[0, 0, [0, 2]], 0.0, atol=1e-12)


@pytest.mark.assets
def test_cmu_neutral_bind_has_no_long_edges(cmu_character, assets_dir):
    """CMU walk: bound at frame 0 the arm-hip web reaches 0.86 m (34x the median edge); bound in
    the neutral pose no edge is longer than 4x the median at any of the 995 frames."""
    from stages.rig.bvh_character import load_bvh_character

    ratios = edge_ratios(cmu_character)
    assert ratios.size == 995 and ratios.max() < 4.0
    for side in ("Left", "Right"):
        assert skin_gap(cmu_character, f"{side}Wrist", ("Hips", "LHipJoint", "RHipJoint", "LeftHip", "RightHip")) > 0.10
    old = load_bvh_character(assets_dir / "cmu_131_01_walk.bvh", bind_pose="frame0")
    assert edge_ratios(old, every=5).max() > 20.0


def test_limbs_found_by_names_when_the_shape_is_ambiguous(tmp_path):
    """Arms straight up in the rest pose and in every frame: a hand is the highest joint, so the
    shape alone finds no head; the names do. Without names the skin falls back to frame 0."""
    from stages.rig.bvh import parse_bvh
    from stages.rig.bvh_character import load_bvh_character
    from stages.rig.neutral_pose import ARM_ANGLE_DEG, neutral_pose

    still = [((0.0, 0.95, 0.0), {})] * 2
    data = parse_bvh(write(tmp_path, humanoid_bvh(arms_up=True, frames=still), "up.bvh"))
    rots, body, _ = neutral_pose(data.parents, data.offsets, data.joint_names)
    assert body.found_by == "names"
    names = data.joint_names
    assert [names[c[0]] for c in body.arms] == ["LeftShoulder", "RightShoulder"]
    assert [names[j] for j in body.thighs] == ["LeftUpLeg", "RightUpLeg"]
    world = forward_kinematics(data.parents, trs_to_matrix(data.offsets, rots))[:, :3, 3]
    d = unit(world[names.index("LeftHand")] - world[names.index("LeftArm")])
    assert np.degrees(np.arccos(-d[1])) == pytest.approx(ARM_ANGLE_DEG, abs=1e-6)
    rename = {n: f"j{k}" for k, (n, _, _) in enumerate(HUMANOID)}
    path = write(tmp_path, humanoid_bvh(rename, arms_up=True, frames=still), "anon.bvh")
    with pytest.warns(UserWarning, match="no humanoid shape found"):
        load_bvh_character(path)


def test_scene_bind_pose_reaches_the_loader(tmp_path):
    from pipeline.run import load_character
    from pipeline.scene import parse_scene_text
    from stages.rig.bvh_character import load_bvh_character

    path = write(tmp_path, humanoid_bvh(), "h.bvh")
    for key, expect in (("", "neutral"), ("bind_pose: frame0", "frame0")):
        scene = parse_scene_text(f"character: {{source: bvh, path: {path}, {key}}}".replace(", }", "}"))
        np.testing.assert_array_equal(load_character(scene).vertices, load_bvh_character(path, bind_pose=expect).vertices)
