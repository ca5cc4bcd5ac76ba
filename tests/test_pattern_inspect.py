"""`inspect PATTERN_specification.json` (issue 39, part 5): the facts of a GarmentCode pattern and a
PNG of its panels, written without a plotting library and read back here with zlib."""
from __future__ import annotations

import json
import math
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from pipeline.pattern_inspect import describe_pattern, pattern_png
from pipeline.pattern_png import fill_polygon
from stages.garments.garmentcode_place import BODY_KEYS

ROOT = Path(__file__).resolve().parents[1]


def read_png(path: Path) -> np.ndarray:
    """(H, W, 3) of an 8-bit RGB PNG with filter 0 rows (what write_png writes)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(data):
        n, tag = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        assert struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])[0] == zlib.crc32(tag + body) & 0xFFFFFFFF
        if tag == b"IHDR":
            w, h = struct.unpack(">II", body[:8])
            assert body[8:10] == b"\x08\x02"
        elif tag == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 3 * w)
    assert (raw[:, 0] == 0).all()
    return raw[:, 1:].reshape(h, w, 3)


def _spec(tmp_path: Path) -> Path:
    """Two panels sewn along one side: a 40 x 60 cm rectangle and a 40 cm wide one with a
    circle-arc hem (radius 30 cm), made for no body beside it."""
    rect = {"translation": [0, 100, 20], "rotation": [0, 0, 0], "vertices": [[0, 0], [40, 0], [40, 60], [0, 60]],
            "edges": [{"endpoints": [i, (i + 1) % 4]} for i in range(4)], "label": "body"}
    arc = {"translation": [0, 100, -20], "rotation": [0, 180, 0], "vertices": [[0, 0], [40, 0], [40, 60], [0, 60]],
           "edges": [{"endpoints": [0, 1], "curvature": {"type": "circle", "params": [30, 0, 0]}},
                     *({"endpoints": [i, (i + 1) % 4]} for i in range(1, 4))]}
    f = tmp_path / "two_specification.json"
    f.write_text(json.dumps({"pattern": {"panels": {"front": rect, "back": arc},
                                         "stitches": [[{"panel": "front", "edge": 1}, {"panel": "back", "edge": 3}]]},
                             "properties": {"curvature_coords": "relative", "units_in_meter": 100}}))
    return f


def test_the_facts_of_a_pattern(tmp_path, monkeypatch):
    monkeypatch.setenv("GARMENT_ASSETS", str(tmp_path / "none"))     # no default body either
    f = describe_pattern(_spec(tmp_path))
    front, back = f["panels"]
    assert (front["name"], front["part"], front["edge_kinds"]) == ("front", "body", {"straight": 4})
    assert front["size_cm"] == [40.0, 60.0] and front["area_cm2"] == pytest.approx(2400.0, rel=1e-6)
    assert back["edge_kinds"] == {"circle": 1, "straight": 3}
    # the arc: chord 40, radius 30 -> half angle asin(2/3); the segment's area is added or cut
    half = math.asin(20 / 30)
    segment = 30 ** 2 * (half - math.sin(2 * half) / 2)
    assert abs(back["area_cm2"] - 2400.0) == pytest.approx(segment, rel=0.02)
    assert f["stitches"] == [{"a": "front.1", "b": "back.3", "length_cm": [60.0, 60.0], "right_wrong": False}]
    assert f["edge_kinds"] == {"straight": 7, "circle": 1}
    # placed: front at z = 0.2 m, back turned 180 degrees about y at z = -0.2 (x from -40 to 40 cm)
    assert f["placed_size_cm"][0] == pytest.approx(80.0, abs=0.1) and f["placed_size_cm"][2] == pytest.approx(40.0)
    assert f["made_for"]["source"] is None and "body" in f["made_for"]["problem"]


def test_the_body_beside_the_pattern_is_named(tmp_path):
    spec = _spec(tmp_path)
    body = tmp_path / "body_measurements.yaml"
    body.write_text("body:\n  height: 180.0\n  waist: 80.0\n")     # a body file short of keys
    made_for = describe_pattern(spec)["made_for"]
    assert made_for["source"] is None and str(body) in made_for["problem"] and "head_l" in made_for["problem"]
    body.write_text("body:\n" + "".join(f"  {k}: {180.0 if k == 'height' else 30.0}\n" for k in BODY_KEYS))
    made_for = describe_pattern(spec)["made_for"]
    assert made_for["source"] == str(body) and made_for["height"] == 180.0


def test_the_png_shows_each_panel_filled_and_its_stitched_edge(tmp_path):
    img = read_png(pattern_png(_spec(tmp_path), tmp_path / "p.png"))
    # 400 px/m, 5 cm margins: the front is 160 x 240 px from (20, 20), the back beside it
    assert img.shape[1] >= 20 + 160 + 20 + 160 and img.shape[0] >= 20 + 240 + 20
    assert tuple(img[140, 100]) == (170, 200, 235)                 # inside the front: the body colour
    assert tuple(img[5, 5]) == (255, 255, 255)                     # the margin
    right_side = img[30:250, 176:184]                              # the front's stitched edge, x = 180 px
    assert ((right_side == (200, 40, 40)).all(axis=2)).any(axis=1).mean() > 0.9


def test_fill_polygon_against_a_brute_force_point_test():
    rng = np.random.default_rng(3)
    for _ in range(5):
        ang = np.sort(rng.uniform(0, 2 * np.pi, 9))
        poly = np.c_[20 + 12 * rng.uniform(0.3, 1, 9) * np.cos(ang), 20 + 12 * rng.uniform(0.3, 1, 9) * np.sin(ang)]
        img = np.zeros((40, 40, 3), np.uint8)
        fill_polygon(img, poly, (1, 1, 1))
        yy, xx = np.mgrid[0:40, 0:40] + 0.5
        inside = np.zeros((40, 40), bool)
        for a, b in zip(poly, np.roll(poly, -1, axis=0)):          # even-odd crossing count per pixel centre
            c = (a[1] <= yy) != (b[1] <= yy)
            x_at = a[0] + (yy - a[1]) / np.where(b[1] != a[1], b[1] - a[1], 1) * (b[0] - a[0])
            inside ^= c & (xx < x_at)
        assert (img[..., 0] == 1).sum() == pytest.approx(inside.sum(), abs=2)
        assert ((img[..., 0] == 1) != inside).sum() <= 2


def test_the_cli_prints_the_facts_and_writes_the_png(tmp_path):
    spec = _spec(tmp_path)
    r = subprocess.run([sys.executable, "-m", "pipeline", "inspect", str(spec), "--png", str(tmp_path / "x.png")],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert "2 panels, 1 stitches" in r.stdout and "front.1" in r.stdout and (tmp_path / "x.png").is_file()
    bad = tmp_path / "bad_specification.json"
    bad.write_text('{"pattern": {"panels": {}}}')
    r = subprocess.run([sys.executable, "-m", "pipeline", "inspect", str(bad)], capture_output=True, text=True,
                       cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and str(bad) in r.stderr
