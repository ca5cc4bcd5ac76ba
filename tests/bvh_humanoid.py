"""A small humanoid BVH written out in tests (T-pose rest, frame 0 with the hands on the hips) and
the measures the neutral-bind tests take on skinned characters."""
from __future__ import annotations

import numpy as np

from stages.rig.transforms import forward_kinematics

# A humanoid in a T-pose rest (metres, Y up, facing +Z, left = +X): (name, parent, offset).
# 'LeftShoulder' is a clavicle here, as in Mixamo rigs (in CMU files it is the upper arm's joint).
HUMANOID = (
    ("Hips", None, (0, 0, 0)), ("Spine", "Hips", (0, 0.12, 0)), ("Chest", "Spine", (0, 0.15, 0)),
    ("Neck", "Chest", (0, 0.2, 0)), ("Head", "Neck", (0, 0.1, 0)), ("Head_end", "Head", (0, 0.15, 0)),
    ("LeftShoulder", "Chest", (0.02, 0.14, 0)), ("LeftArm", "LeftShoulder", (0.15, 0, 0)),
    ("LeftForeArm", "LeftArm", (0.28, 0, 0)), ("LeftHand", "LeftForeArm", (0.25, 0, 0)),
    ("LeftHand_end", "LeftHand", (0.15, 0, 0)),
    ("RightShoulder", "Chest", (-0.02, 0.14, 0)), ("RightArm", "RightShoulder", (-0.15, 0, 0)),
    ("RightForeArm", "RightArm", (-0.28, 0, 0)), ("RightHand", "RightForeArm", (-0.25, 0, 0)),
    ("RightHand_end", "RightHand", (-0.15, 0, 0)),
    ("LeftUpLeg", "Hips", (0.09, -0.05, 0)), ("LeftLeg", "LeftUpLeg", (0, -0.42, 0)),
    ("LeftFoot", "LeftLeg", (0, -0.4, 0)), ("LeftToe", "LeftFoot", (0, -0.05, 0.12)),
    ("LeftToe_end", "LeftToe", (0, 0, 0.06)),
    ("RightUpLeg", "Hips", (-0.09, -0.05, 0)), ("RightLeg", "RightUpLeg", (0, -0.42, 0)),
    ("RightFoot", "RightLeg", (0, -0.4, 0)), ("RightToe", "RightFoot", (0, -0.05, 0.12)),
    ("RightToe_end", "RightToe", (0, 0, 0.06)),
)


def humanoid_frames(n=13):
    """Frame 0: hands on the hips (elbows out, hands down along the hip), turned 20 degrees about Y;
    then the arms hang and swing +-30 degrees while the legs stride and the root walks along +Z.
    {joint: (Zrot, Xrot, Yrot)} per frame plus the root position; the right side mirrors Z."""
    out = []
    for k in range(n):
        phase = np.sin(2 * np.pi * k / 8)
        if k == 0:
            arm = {"LeftArm": (-44.4, 0, 0), "LeftForeArm": (-88.3, 0, 0), "LeftHand": (42.7, 0, 0)}
        else:
            arm = {"LeftArm": (-80, 0, 30 * phase), "LeftForeArm": (-10, 0, 0)}
        rot = dict(arm)
        rot.update({k2.replace("Left", "Right"): (-z, x, -y) for k2, (z, x, y) in arm.items()})
        rot["LeftUpLeg"], rot["RightUpLeg"] = (0, -25 * phase, 0), (0, 25 * phase, 0)
        rot["Hips"] = (0, 0, 20)
        out.append(((0.0, 0.95, 0.1 * k), rot))
    return out


def humanoid_bvh(names=None, clavicles=True, floor_root=False, arms_up=False, frames=None) -> str:
    """HUMANOID as BVH text. names: optional {name: new name}; clavicles=False joins each upper arm
    to the chest (offset = clavicle + shoulder offsets); floor_root: a 'Root' joint on the floor
    carries the motion, Hips hangs 0.95 m above it; arms_up: the rest pose has the arms straight up."""
    joints = [list(j) for j in HUMANOID]
    if not clavicles:
        for side, sx in (("Left", 1), ("Right", -1)):
            joints = [j for j in joints if j[0] != f"{side}Shoulder"]
            arm = next(j for j in joints if j[0] == f"{side}Arm")
            arm[1], arm[2] = "Chest", (0.17 * sx, 0.14, 0)
    if arms_up:
        for j in joints:
            if any(w in j[0] for w in ("Arm", "Hand")) and j[2][1] == 0:
                j[2] = (0, abs(j[2][0]), 0)
    if floor_root:
        joints = [["Root", None, (0, 0, 0)], ["Hips", "Root", (0, 0.95, 0)]] + joints[1:]
    kids = {}
    for name, parent, _ in joints:
        kids.setdefault(parent, []).append(name)
    offset = {n: o for n, _, o in joints}
    order, lines = [], ["HIERARCHY"]

    def emit(name, depth):
        pad = "  " * depth
        label = (names or {}).get(name, name)
        if name.endswith("_end"):
            lines.extend([pad + "End Site", pad + "{", pad + "  OFFSET %g %g %g" % offset[name], pad + "}"])
            return
        order.append(name)
        lines.extend([pad + ("ROOT " if depth == 0 else "JOINT ") + label, pad + "{", pad + "  OFFSET %g %g %g" % offset[name]])
        lines.append(pad + ("  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if depth == 0
                            else "  CHANNELS 3 Zrotation Xrotation Yrotation"))
        for c in kids.get(name, []):
            emit(c, depth + 1)
        lines.append(pad + "}")

    emit(joints[0][0], 0)
    frames = humanoid_frames() if frames is None else frames
    lines += ["MOTION", f"Frames: {len(frames)}", "Frame Time: 0.1"]
    for root, rot in frames:
        vals = list(root) if not floor_root else [root[0], 0.0, root[2]]
        if floor_root:
            rot = dict(rot, Root=rot.get("Hips", (0, 0, 0)), Hips=(0, 0, 0))
        for n in order:
            vals += list(rot.get(n, (0, 0, 0)))
        lines.append(" ".join("%.6g" % v for v in vals))
    return "\n".join(lines) + "\n"


def edge_ratios(character, every=1) -> np.ndarray:
    """Per frame of the clip: longest skinned edge / median skinned edge."""
    from stages.rig.skinning import sample_motion, skin

    v = skin(character, sample_motion(character, 0, character.clip(0).times[::every]))
    t = character.triangles
    e = np.unique(np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1), axis=0)
    length = np.linalg.norm(v[:, e[:, 0]] - v[:, e[:, 1]], axis=2)
    return length.max(axis=1) / np.median(length, axis=1)


def skin_gap(character, hand_joint: str, body_joints) -> float:
    """Least distance from the skin of `hand_joint` and below (dominant weight) to the skin of
    `body_joints`, in the bind pose."""
    from scipy.spatial import cKDTree
    from stages.rig.neutral_pose import subtree

    n = character.joint_names
    dom = character.skin_joints[np.arange(len(character.vertices)), character.skin_weights.argmax(axis=1)]
    hand = character.vertices[np.isin(dom, subtree(character.parents, n.index(hand_joint)))]
    body = character.vertices[np.isin(dom, [n.index(b) for b in body_joints])]
    return float(cKDTree(body).query(hand)[0].min())


def bind_positions(character) -> dict:
    world = forward_kinematics(character.parents, character.rest_local)
    return {n: world[j, :3, 3] for j, n in enumerate(character.joint_names)}


def unit(v):
    return np.asarray(v) / np.linalg.norm(v)
