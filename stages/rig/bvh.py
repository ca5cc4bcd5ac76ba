"""BVH motion capture: the parser and the clip.

Conventions followed (BVH has no formal spec; these match the CMU / Biovision files and
Blender's importer):

- Rotation channels are Euler angles in degrees, applied in the order they are *listed*, intrinsic:
  ``CHANNELS 3 Zrotation Xrotation Yrotation`` gives ``R = Rz @ Rx @ Ry`` (column vectors). Any
  subset of the three axes is allowed; a joint without rotation channels does not rotate.
- Position channels REPLACE the joint's OFFSET component-wise (``Yposition`` alone replaces only
  the y of the offset). For the root this makes them the root position in the world.
- The joint's local transform is ``T(translation) @ R``; world = parent_world @ local.
- ``scale`` multiplies OFFSETs and position channels (not angles).
- ``End Site`` blocks become extra leaf joints named ``<parent>_end`` (no channels), placed in
  file order right after their parent's subtree content, so bones to the end have a length.
- Only one ROOT hierarchy is supported: a second ROOT is an InputError (a Character has one root,
  and a synthetic root would carry no motion, breaking the relative-frame simulation).
- MOTION: 'Frames: N' and 'Frame Time: dt' (colon optional), then N x C numbers, one frame per
  line as usual or in any whitespace layout when the total count is exactly N x C.

The skinned character built around the skeleton: stages/rig/bvh_character.py.

CMU 131_01 (measured): 31 joints + 7 end sites = 38 Character joints, 96 channels, 995 frames,
Frame Time 0.008333 s (120 Hz), metres, Y up, facing +Z; the subject stands (~0-2.5 s), kneels
on one knee (~2.7-3.7 s), walks ~2.3 m along +Z (~4-6.7 s) and stands.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stages.checks import ContractError, check_array
from stages.errors import InputError
from stages.rig.transforms import forward_kinematics, trs_to_matrix
from stages.rig.types import Clip

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CANONICAL = {c.lower(): c for c in CHANNEL_NAMES}
_TOKEN = re.compile(r"[{}]|[^\s{}]+")


@dataclass(frozen=True)
class BvhData:
    """A parsed BVH file, in file order.

    joint_names: J unique names; end sites are joints named '<parent>_end' (made unique).
    parents: (J,) int32, parent index, -1 for the root; parents[j] < j (file order).
    offsets: (J, 3) float64, metres (after `scale`), each joint's OFFSET in its parent's frame.
    channels: J tuples of canonical channel names ('Xposition' ... 'Zrotation'), in file order;
        empty for end sites and channel-less joints.
    channel_start: (J,) int32, column of each joint's first channel in `frames`.
    end_site: (J,) bool, True for joints that came from an End Site block.
    frame_time: seconds between frames (> 0), as written in the file.
    frames: (F, C) float64, F >= 1, C = total channel count; rotations in degrees, positions in
        metres (after `scale`).
    source: the file path, for error messages and metadata.
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    channel_start: np.ndarray
    end_site: np.ndarray
    frame_time: float
    frames: np.ndarray
    source: str = ""

    def __post_init__(self):
        o = "BvhData"
        nj = len(self.joint_names)
        if nj == 0:
            raise ContractError(f"{o}.joint_names: no joints")
        if len(set(self.joint_names)) != nj:
            raise ContractError(f"{o}.joint_names: names must be unique")
        p = check_array(o, "parents", self.parents, (nj,), np.int32)
        if p[0] != -1 or np.any(p[1:] < 0) or np.any(p[1:] >= np.arange(1, nj)):
            raise ContractError(f"{o}.parents: expected parents[0] == -1 and 0 <= parents[j] < j for j > 0")
        check_array(o, "offsets", self.offsets, (nj, 3), np.float64)
        if len(self.channels) != nj:
            raise ContractError(f"{o}.channels: expected {nj} channel lists, got {len(self.channels)}")
        cs = check_array(o, "channel_start", self.channel_start, (nj,), np.int32)
        es = check_array(o, "end_site", self.end_site, (nj,), np.bool_)
        counts = np.array([len(c) for c in self.channels], dtype=np.int64)
        if np.any(cs != np.concatenate([[0], np.cumsum(counts)[:-1]])):
            raise ContractError(f"{o}.channel_start: must be the running sum of channel counts")
        if np.any(counts[es] != 0):
            raise ContractError(f"{o}.channels: end sites have no channels")
        if not (np.isfinite(self.frame_time) and self.frame_time > 0):
            raise ContractError(f"{o}.frame_time: expected a positive number, got {self.frame_time}")
        f = check_array(o, "frames", self.frames, (None, int(counts.sum())), np.float64)
        if f.shape[0] == 0:
            raise ContractError(f"{o}.frames: at least one frame is needed")

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.frames.shape[1])


# ---------------------------------------------------------------------------------------- parsing


def _tokens(lines: list[str], start: int, stop: int) -> list[tuple[str, int]]:
    """(token, 1-based line number) for lines[start:stop]; braces are separate tokens."""
    out = []
    for i in range(start, stop):
        out.extend((t, i + 1) for t in _TOKEN.findall(lines[i]))
    return out


def _number(src, tok: str, line: int, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(src, f"line {line}: bad number {tok!r} in {what}") from None
    if not np.isfinite(v):
        raise InputError(src, f"line {line}: non-finite number {tok!r} in {what}")
    if abs(v) > MAX_ABS:
        raise InputError(src, f"line {line}: {tok!r} in {what} is beyond +-{MAX_ABS:g} (no BVH length in "
                              f"centimetres or angle in degrees is)")
    return v


# Larger values are corrupt data: a length of 10 km in centimetres, or an angle of 1e6 degrees
# (which the motion code would carry to overflows and NaN before any check).
MAX_ABS = 1e6


class _HierarchyParser:
    def __init__(self, src, toks: list[tuple[str, int]], end_line: int):
        self.src = src
        self.toks = toks
        self.i = 0
        self.end_line = end_line  # where the hierarchy text stops (MOTION line or end of file)
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[tuple[float, float, float]] = []
        self.channels: list[tuple[str, ...]] = []
        self.end_site: list[bool] = []

    def fail(self, line: int, problem: str):
        raise InputError(self.src, f"line {line}: {problem}")

    def peek(self) -> tuple[str, int] | None:
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self, what: str) -> tuple[str, int]:
        t = self.peek()
        if t is None:
            self.fail(self.end_line, f"hierarchy ends while expecting {what}")
        self.i += 1
        return t

    def expect_open(self, opened: str, line: int):
        tok, ln = self.take(f"'{{' after {opened}")
        if tok != "{":
            self.fail(ln, f"expected '{{' after {opened} (line {line}), got {tok!r}")

    def parse(self):
        roots = 0
        while self.peek() is not None:
            tok, ln = self.take("ROOT")
            if tok == "}":
                self.fail(ln, "unbalanced braces: '}' without a matching '{'")
            if tok.upper() != "ROOT":
                self.fail(ln, f"expected ROOT, got {tok!r}")
            if roots:
                self.fail(ln, "a second ROOT hierarchy is not supported (a character needs one root joint)")
            roots += 1
            self.joint(-1, ln, "ROOT")
        if roots == 0:
            self.fail(self.end_line, "HIERARCHY has no ROOT joint")

    def joint_name(self, line: int, keyword: str) -> str:
        # A name is everything on the keyword's line before '{' (names with spaces exist).
        parts = []
        while (t := self.peek()) is not None and t[1] == line and t[0] != "{":
            parts.append(t[0])
            self.i += 1
        if not parts:
            self.fail(line, f"{keyword} without a name")
        return " ".join(parts)

    def add(self, name: str, parent: int, end: bool) -> int:
        self.names.append(name)
        self.parents.append(parent)
        self.offsets.append(None)
        self.channels.append(())
        self.end_site.append(end)
        return len(self.names) - 1

    def offset(self, j: int, line: int):
        if self.offsets[j] is not None:
            self.fail(line, f"second OFFSET for joint {self.names[j]!r}")
        vals = []
        for _ in range(3):
            tok, ln = self.take("three OFFSET numbers")
            vals.append(_number(self.src, tok, ln, "OFFSET"))
        self.offsets[j] = tuple(vals)

    def channel_list(self, j: int, line: int):
        if self.channels[j]:
            self.fail(line, f"second CHANNELS for joint {self.names[j]!r}")
        tok, ln = self.take("the channel count")
        try:
            n = int(tok)
        except ValueError:
            self.fail(ln, f"bad channel count {tok!r} after CHANNELS")
        if not 0 <= n <= 6:
            self.fail(ln, f"CHANNELS {n}: a joint has 0 to 6 channels")
        names = []
        for _ in range(n):
            tok, ln = self.take(f"{n} channel names")
            c = _CANONICAL.get(tok.lower())
            if c is None:
                if tok == "}" or tok.upper() in ("JOINT", "OFFSET", "CHANNELS", "END"):
                    self.fail(line, f"CHANNELS {n} lists only {len(names)} channel names")
                self.fail(ln, f"unknown channel {tok!r} (expected one of {', '.join(CHANNEL_NAMES)})")
            if c in names:
                self.fail(ln, f"channel {c} listed twice for joint {self.names[j]!r}")
            names.append(c)
        self.channels[j] = tuple(names)

    def joint(self, parent: int, line: int, keyword: str):
        name = self.joint_name(line, keyword)
        j = self.add(name, parent, False)
        self.expect_open(f"{keyword} {name}", line)
        while True:
            if self.peek() is None:
                self.fail(self.end_line, f"unbalanced braces: {keyword} {name} opened at line {line} is not closed")
            tok, ln = self.take("")
            key = tok.upper()
            if tok == "}":
                break
            if key == "OFFSET":
                self.offset(j, ln)
            elif key == "CHANNELS":
                self.channel_list(j, ln)
            elif key == "JOINT":
                self.joint(j, ln, "JOINT")
            elif key == "END":
                site, sln = self.take("'Site' after End")
                if site.upper() != "SITE":
                    self.fail(sln, f"expected 'End Site', got 'End {site}'")
                self.end(j, ln)
            elif key == "ROOT":
                self.fail(ln, f"unbalanced braces: ROOT inside {keyword} {name} (opened at line {line} and not closed)")
            else:
                self.fail(ln, f"unexpected {tok!r} in {keyword} {name}")
        if self.offsets[j] is None:
            self.fail(line, f"{keyword} {name} has no OFFSET")

    def end(self, parent: int, line: int):
        j = self.add(f"{self.names[parent]}_end", parent, True)
        self.expect_open("End Site", line)
        while True:
            if self.peek() is None:
                self.fail(self.end_line, f"unbalanced braces: End Site opened at line {line} is not closed")
            tok, ln = self.take("")
            if tok == "}":
                break
            if tok.upper() == "OFFSET":
                self.offset(j, ln)
            else:
                self.fail(ln, f"unexpected {tok!r} in End Site (only OFFSET is allowed)")
        if self.offsets[j] is None:
            self.fail(line, "End Site has no OFFSET")


def _unique_names(names: list[str], end_site: list[bool]) -> tuple[tuple[str, ...] | None, str | None]:
    """(names, None), or (None, a duplicated real name). Generated end-site names get a numeric
    suffix when they clash with another name."""
    real = [n for n, e in zip(names, end_site) if not e]
    seen: set[str] = set()
    for n in real:
        if n in seen:
            return None, n
        seen.add(n)
    out = []
    for n, e in zip(names, end_site):
        if e:
            base, k = n, 1
            while n in seen:
                k += 1
                n = f"{base}{k}"
            seen.add(n)
        out.append(n)
    return tuple(out), None


_FRAMES = re.compile(r"^\s*frames\s*:?\s*(\S*)\s*$", re.IGNORECASE)
_FRAME_TIME = re.compile(r"^\s*frame\s+time\s*:?\s*(\S*)\s*$", re.IGNORECASE)


def _header_value(src, lines, i, pattern, label) -> tuple[str, int]:
    """Find the next non-blank line at or after i, which must match `pattern`."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise InputError(src, f"line {len(lines)}: MOTION ends before '{label}'")
    m = pattern.match(lines[i])
    if m is None:
        raise InputError(src, f"line {i + 1}: expected '{label} <number>', got {lines[i].strip()!r}")
    return m.group(1), i


def parse_bvh(path, *, scale: float = 1.0) -> BvhData:
    """Parse a BVH file (HIERARCHY + MOTION) into file-order joints and a frame matrix.

    path: file path. scale: multiplies OFFSETs and position channels (e.g. 0.01 for centimetres;
    the CMU file in shared assets is already in metres).
    Raises InputError(path, problem) for anything malformed, with the line number where one applies.
    """
    src = str(path)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(src, f"scale must be a positive number, got {scale}")
    from stages.input_files import read_bytes
    text = read_bytes(Path(path), "BVH file").decode("utf-8-sig", errors="replace")   # a FIFO: refused unopened
    lines = text.splitlines()
    if not text.strip():
        raise InputError(src, "empty file")

    first = next(i for i, ln in enumerate(lines) if ln.strip())
    if lines[first].split()[0].upper() != "HIERARCHY":
        raise InputError(src, f"line {first + 1}: expected HIERARCHY, got {lines[first].strip()[:40]!r}")
    hier_tail = lines[first].split(None, 1)[1:]  # anything after HIERARCHY on its line
    motion = next((i for i in range(first + 1, len(lines)) if lines[i].split()[:1] and lines[i].split()[0].upper() == "MOTION"), None)
    stop = motion if motion is not None else len(lines)

    toks = [(t, first + 1) for t in _TOKEN.findall(hier_tail[0])] if hier_tail else []
    toks += _tokens(lines, first + 1, stop)
    hp = _HierarchyParser(src, toks, stop + 1 if motion is not None else len(lines))
    hp.parse()
    if motion is None:
        raise InputError(src, "no MOTION section after the hierarchy")

    names, clash = _unique_names(hp.names, hp.end_site)
    if clash is not None:
        raise InputError(src, f"joint name {clash!r} is used twice")
    counts = np.array([len(c) for c in hp.channels], dtype=np.int32)
    n_channels = int(counts.sum())

    # MOTION header: "Frames: N" then "Frame Time: dt" (the colon is optional, any spacing).
    rest = lines[motion].split(None, 1)[1:]
    if rest and rest[0].strip():
        raise InputError(src, f"line {motion + 1}: unexpected text after MOTION")
    tok, i = _header_value(src, lines, motion + 1, _FRAMES, "Frames:")
    try:
        n_frames = int(tok)
    except ValueError:
        raise InputError(src, f"line {i + 1}: bad frame count {tok!r}") from None
    if n_frames < 1:
        raise InputError(src, f"line {i + 1}: Frames: {n_frames} (a clip needs at least one frame)")
    tok, i = _header_value(src, lines, i + 1, _FRAME_TIME, "Frame Time:")
    frame_time = _number(src, tok, i + 1, "Frame Time")
    if frame_time <= 0:
        raise InputError(src, f"line {i + 1}: Frame Time must be positive, got {frame_time}")

    frames = _parse_frames(src, lines, i + 1, n_frames, n_channels)

    offsets = np.array(hp.offsets, dtype=np.float64) * scale
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
    for j, chans in enumerate(hp.channels):
        for k, c in enumerate(chans):
            if c.endswith("position"):
                frames[:, starts[j] + k] *= scale
    return BvhData(
        joint_names=names,
        parents=np.array(hp.parents, dtype=np.int32),
        offsets=offsets,
        channels=tuple(hp.channels),
        channel_start=starts,
        end_site=np.array(hp.end_site, dtype=np.bool_),
        frame_time=float(frame_time),
        frames=frames,
        source=src,
    )


def _parse_frames(src, lines: list[str], start: int, n_frames: int, n_channels: int) -> np.ndarray:
    """The F x C numbers after 'Frame Time:'.

    One frame per line is the norm; any other whitespace layout is accepted when the total count
    is exactly F x C. Otherwise the error names the first line that breaks the one-frame-per-line
    layout, or says how many frames are missing.
    """
    rows = [(i + 1, lines[i].split()) for i in range(start, len(lines)) if lines[i].strip()]
    total = sum(len(r) for _, r in rows)
    expected = n_frames * n_channels
    if total != expected:
        if n_channels > 0:
            for k, (ln, r) in enumerate(rows):
                if len(r) != n_channels:
                    if k < n_frames:
                        raise InputError(src, f"line {ln}: frame {k} has {len(r)} values, expected {n_channels} (the hierarchy's channel count)")
                    break
        n_lines = len(rows)
        if total < expected:
            raise InputError(src, f"fewer frames than declared: Frames: {n_frames} but only {n_lines} frame lines ({total} of {expected} values)")
        ln = rows[n_frames][0] if len(rows) > n_frames else rows[-1][0]
        raise InputError(src, f"line {ln}: more frame data than declared (Frames: {n_frames}, {n_channels} channels each)")
    flat = [t for _, r in rows for t in r]
    try:
        data = np.array(flat, dtype=np.float64)
    except ValueError:
        for ln, r in rows:
            for t in r:
                _number(src, t, ln, "MOTION data")
        raise  # unreachable: one token above failed
    if not np.all(np.isfinite(data) & (np.abs(data) <= MAX_ABS)):
        pos = int(np.argmax(~(np.isfinite(data) & (np.abs(data) <= MAX_ABS))))
        seen = 0
        for ln, r in rows:
            if pos < seen + len(r):
                _number(src, r[pos - seen], ln, "MOTION data")   # raises: names the line and the value
            seen += len(r)
    return data.reshape(n_frames, n_channels)


# ------------------------------------------------------------------------------------------- clip


def _local_trs(data: BvhData, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local translations (K, J, 3) and xyzw rotations (K, J, 4) at frames `idx`."""
    f = data.frames[idx]
    k, nj = f.shape[0], data.n_joints
    trans = np.broadcast_to(data.offsets, (k, nj, 3)).copy()
    rots = np.zeros((k, nj, 4))
    rots[..., 3] = 1.0
    for j, chans in enumerate(data.channels):
        s = int(data.channel_start[j])
        axes, cols = "", []
        for c, name in enumerate(chans):
            if name.endswith("position"):
                trans[:, j, "XYZ".index(name[0])] = f[:, s + c]  # position channels replace the offset
            else:
                axes += name[0]
                cols.append(s + c)
        if axes:
            # Uppercase = intrinsic in scipy: R = R_axes[0] @ R_axes[1] @ R_axes[2], listed order.
            rots[:, j] = Rotation.from_euler(axes, f[:, cols], degrees=True).as_quat()
    return trans, rots


def _frame_indices(data: BvhData, frames) -> np.ndarray:
    idx = np.arange(data.n_frames)
    if frames is None:
        return idx
    if isinstance(frames, slice):
        out = idx[frames]
    else:
        out = np.asarray(frames)
        if out.ndim == 0:
            out = out[None]
        if out.dtype.kind not in "iu":
            raise ValueError(f"bvh_clip: frames must be a slice or integer indices, got dtype {out.dtype}")
        if out.size and (out.min() < -data.n_frames or out.max() >= data.n_frames):
            raise ValueError(f"bvh_clip: frame index out of range [0, {data.n_frames})")
        out = idx[out]
    if out.size == 0:
        raise ValueError("bvh_clip: no frames selected")
    if out.size > 1 and not np.all(np.diff(out) > 0):
        raise ValueError("bvh_clip: frame indices must be strictly increasing")
    return out


def bvh_clip(data: BvhData, name: str = "bvh", frames=None) -> Clip:
    """The BVH motion as a Clip of local TRS keys, one key per selected frame.

    frames: None (all), a slice, or strictly increasing frame indices. Key times are
    (index - first index) * frame_time, so the clip starts at t = 0. Joints (end sites included)
    keep the BvhData order; scales are 1; linear interpolation, no looping.
    """
    idx = _frame_indices(data, frames)
    trans, rots = _local_trs(data, idx)
    return Clip(
        name=name,
        times=(idx - idx[0]).astype(np.float64) * data.frame_time,
        translations=trans,
        rotations=rots,
        scales=np.ones_like(trans),
        interpolation="linear",
        loop=False,
    )


def bvh_world(data: BvhData, frames=None) -> np.ndarray:
    """World joint transforms (K, J, 4, 4) at the selected frames (forward kinematics of the clip)."""
    idx = _frame_indices(data, frames)
    trans, rots = _local_trs(data, idx)
    return forward_kinematics(data.parents, trs_to_matrix(trans, rots))
