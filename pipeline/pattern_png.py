"""A PNG of flat sewing-pattern panels, drawn with numpy and written with zlib (no plotting library):
each panel filled by scanlines in its part's colour, its outline dark and its stitched edges red."""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

PART_RGB = {"body": (170, 200, 235), "leg": (180, 225, 180), "arm": (240, 210, 160)}
OUTLINE = (40, 40, 40)
STITCHED = (200, 40, 40)
BACKGROUND = (255, 255, 255)


def write_png(path: Path, rgb: np.ndarray) -> None:
    """An 8-bit RGB PNG of an (H, W, 3) uint8 array."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))    # filter 0 on every row

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


def fill_polygon(img: np.ndarray, poly: np.ndarray, rgb) -> None:
    """Fill the pixels whose centres are inside the closed polygon (N, 2), pixel units, even-odd."""
    a, b = poly, np.roll(poly, -1, axis=0)
    y0, y1 = max(int(np.floor(poly[:, 1].min())), 0), min(int(np.ceil(poly[:, 1].max())), img.shape[0] - 1)
    for y in range(y0, y1 + 1):
        yc = y + 0.5
        cross = (a[:, 1] <= yc) != (b[:, 1] <= yc)
        if not cross.any():
            continue
        xa, xb, ya, yb = a[cross, 0], b[cross, 0], a[cross, 1], b[cross, 1]
        xs = np.sort(xa + (yc - ya) / (yb - ya) * (xb - xa))
        for l, r in zip(xs[0::2], xs[1::2]):
            i0, i1 = max(int(np.ceil(l - 0.5)), 0), min(int(np.floor(r - 0.5)), img.shape[1] - 1)
            if i1 >= i0:
                img[y, i0:i1 + 1] = rgb


def draw_polyline(img: np.ndarray, pts: np.ndarray, rgb, width: int = 1) -> None:
    """Set the pixels along an open polyline (M, 2), pixel units, sampled at under a pixel."""
    for p, q in zip(pts[:-1], pts[1:]):
        n = max(int(np.ceil(np.abs(q - p).max() * 2)), 1)
        s = p + (q - p) * (np.arange(n + 1) / n)[:, None]
        for dy in range(-(width // 2), width - width // 2):
            for dx in range(-(width // 2), width - width // 2):
                ix = np.clip(np.floor(s[:, 0]).astype(int) + dx, 0, img.shape[1] - 1)
                iy = np.clip(np.floor(s[:, 1]).astype(int) + dy, 0, img.shape[0] - 1)
                img[iy, ix] = rgb


def panels_image(panels: list, px_per_m: float = 400.0, gap: float = 0.05, row_width: float = 2.0) -> np.ndarray:
    """(H, W, 3) uint8 of flat panels laid out left to right in rows at most `row_width` m wide.
    panels: dicts with 'outline' (N, 2) m, 'part', and 'stitched' (list of (M, 2) m polylines)."""
    boxes, x, y, row_h, width = [], gap, gap, 0.0, 0.0
    for p in panels:
        lo, hi = p["outline"].min(axis=0), p["outline"].max(axis=0)
        w, h = hi - lo
        if x > gap and x + w > row_width:
            x, y, row_h = gap, y + row_h + gap, 0.0
        boxes.append((x - lo[0], y + hi[1]))     # the first row on top; y up in a panel, down in the image
        x, row_h, width = x + w + gap, max(row_h, h), max(width, x + w + gap)
    height = y + row_h + gap
    img = np.empty((int(np.ceil(height * px_per_m)), int(np.ceil(width * px_per_m)), 3), np.uint8)
    img[:] = BACKGROUND

    def to_px(pts, off):
        return np.stack([pts[:, 0] + off[0], off[1] - pts[:, 1]], axis=1) * px_per_m

    for p, off in zip(panels, boxes):
        outline = to_px(p["outline"], off)
        fill_polygon(img, outline, PART_RGB.get(p["part"], PART_RGB["body"]))
        draw_polyline(img, np.vstack([outline, outline[:1]]), OUTLINE)
        for s in p["stitched"]:
            draw_polyline(img, to_px(s, off), STITCHED, width=2)
    return img
