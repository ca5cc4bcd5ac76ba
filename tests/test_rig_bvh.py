"""BVH parser, clip and character: hand-made files checked against hand-built rotation matrices."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.errors import InputError
from stages.rig.bvh import bvh_clip, parse_bvh
from stages.rig.transforms import forward_kinematics, trs_to_matrix


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
    with pytest.raises(InputError, match="cannot read"):
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
