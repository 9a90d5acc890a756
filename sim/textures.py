"""Seeded procedural textures (uint8 RGB arrays, rows top to bottom) that are not repetitive.

Everything is built from upsampled multi-octave value noise plus randomly jittered shapes, so
every patch looks different and ORB finds distinctive corners (repetitive checkers would give
ambiguous matches). `rich=False` gives low-contrast, nearly flat textures (the `poor` knob).
"""

from __future__ import annotations

import colorsys

import cv2
import numpy as np


def value_noise(rng: np.random.Generator, h: int, w: int, octaves: int = 5, base: int = 4,
                persistence: float = 0.55) -> np.ndarray:
    """(h, w) float32 noise in [0, 1]: random grids of growing resolution, cubic-upsampled and summed."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        gh = max(2, min(h, base * 2 ** o * h // max(h, w) + 2))
        gw = max(2, min(w, base * 2 ** o * w // max(h, w) + 2))
        grid = rng.random((gh, gw), dtype=np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= persistence
    out /= total
    lo, hi = np.percentile(out, (1, 99))
    return np.clip((out - lo) / max(hi - lo, 1e-6), 0.0, 1.0)


def _rgb(rng: np.random.Generator, hue: float | None = None, sat: tuple[float, float] = (0.3, 0.9),
         val: tuple[float, float] = (0.3, 0.95)) -> np.ndarray:
    h = rng.random() if hue is None else hue
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, rng.uniform(*sat), rng.uniform(*val))
    return np.array([r, g, b], np.float32) * 255.0


def _shade(color: np.ndarray, noise: np.ndarray, contrast: float) -> np.ndarray:
    """Colour modulated by noise: color * (1 + contrast*(noise-0.5)), (h, w, 3) float32."""
    return color[None, None, :] * (1.0 + contrast * (noise[..., None] - 0.5))


def _finish(img: np.ndarray, rich: bool) -> np.ndarray:
    if not rich:  # flatten towards the mean colour: low contrast, few corners
        mean = img.reshape(-1, 3).mean(axis=0)
        img = mean + 0.12 * (img - mean)
    return np.clip(img, 0, 255).astype(np.uint8)


def _rects(img: np.ndarray, rng: np.random.Generator, n: int, size: tuple[float, float],
           colors: list[np.ndarray] | None = None, alpha: float = 1.0) -> None:
    """Paint n random axis-aligned rectangles (sizes as fractions of the image) in place."""
    h, w = img.shape[:2]
    for _ in range(n):
        rh = max(1, int(h * rng.uniform(*size)))
        rw = max(1, int(w * rng.uniform(*size)))
        y0, x0 = int(rng.integers(0, max(1, h - rh))), int(rng.integers(0, max(1, w - rw)))
        c = colors[int(rng.integers(len(colors)))] if colors else _rgb(rng)
        img[y0:y0 + rh, x0:x0 + rw] = (1 - alpha) * img[y0:y0 + rh, x0:x0 + rw] + alpha * c


def vehicle_paint(rng: np.random.Generator, size: int, rich: bool = True, side_m: float = 2.0) -> np.ndarray:
    """Car paint: a base colour with noise, random stripes, decals and dirt, for a texture that spans
    side_m x side_m metres: decals (0.08-0.44 m), badges and stripes keep their size in metres and their
    number per square metre whatever side_m is (the default 2 m draws what a 2 m sign board shows)."""
    scale = 2.0 / side_m  # fraction of the image per fraction of a 2 m texture
    area = (side_m / 2.0) ** 2
    base = _rgb(rng, sat=(0.2, 0.9), val=(0.35, 0.95))
    img = _shade(base, value_noise(rng, size, size, octaves=6, base=3), 0.5)
    if rng.random() < 0.7:  # stripes along the body
        for _ in range(int(rng.integers(1, 4) * side_m / 2.0)):
            y0 = int(rng.integers(0, size - 4))
            img[y0:y0 + max(2, int(rng.integers(2, max(3, size // 12)) * scale))] = _rgb(rng)
    _rects(img, rng, int(rng.integers(6, 14) * area), (0.04 * scale, 0.22 * scale))  # decals, number plates
    for _ in range(int(rng.integers(3, 8) * area)):  # round badges
        c = (int(rng.integers(0, size)), int(rng.integers(0, size)))
        cv2.circle(img, c, max(2, int(rng.integers(3, max(4, size // 10)) * scale)), _rgb(rng).tolist(), -1)
    dirt = value_noise(rng, size, size, octaves=4, base=8)
    img *= (0.75 + 0.25 * dirt)[..., None]
    return _finish(img, rich)


def glass(rng: np.random.Generator, size: int, rich: bool = True) -> np.ndarray:
    """Dark window glass with reflections."""
    base = np.array([40, 50, 62], np.float32) * rng.uniform(0.7, 1.3)
    img = _shade(base, value_noise(rng, size, size, octaves=5, base=2), 1.4)
    _rects(img, rng, int(rng.integers(2, 6)), (0.05, 0.3), [np.array([150, 160, 170], np.float32)], 0.35)
    return _finish(img, rich)


def facade(rng: np.random.Generator, width_m: float, height_m: float, px_per_m: float = 16.0,
           max_px: int = 512, rich: bool = True) -> np.ndarray:
    """Building facade: wall noise, floors of jittered windows, a shop front at street level."""
    w = int(min(max_px, max(32, width_m * px_per_m)))
    h = int(min(max_px, max(32, height_m * px_per_m)))
    sx, sy = w / width_m, h / height_m
    wall = _rgb(rng, sat=(0.05, 0.45), val=(0.45, 0.9))
    img = _shade(wall, value_noise(rng, h, w, octaves=6, base=4), 0.45)
    floor_h = rng.uniform(2.8, 3.6)
    n_floors = max(1, int(height_m / floor_h))
    win_w, win_h = rng.uniform(0.9, 1.6), rng.uniform(1.2, 1.8)
    pitch = rng.uniform(2.2, 3.5)
    n_cols = max(1, int(width_m / pitch))
    frame = _rgb(rng, sat=(0.0, 0.3), val=(0.2, 0.95))
    for f in range(1, n_floors):  # floor 0 is the shop front
        y_top = h - (f + 1) * floor_h * sy + rng.uniform(0.3, 0.6) * sy
        for c in range(n_cols):
            if rng.random() < 0.08:
                continue
            x0 = (c + 0.5) * width_m / n_cols - win_w / 2 + rng.normal(0, 0.08)
            y0 = int(y_top + rng.normal(0, 0.05) * sy)
            x0p, x1p = int(x0 * sx), int((x0 + win_w * rng.uniform(0.9, 1.1)) * sx)
            y1 = int(y0 + win_h * rng.uniform(0.9, 1.1) * sy)
            cv2.rectangle(img, (x0p - 2, y0 - 2), (x1p + 2, y1 + 2), frame.tolist(), -1)
            pane = np.array([30, 40, 55], np.float32) + rng.uniform(0, 120) * np.array([1, 1, 0.9], np.float32)
            img[max(y0, 0):max(y1, 0), max(x0p, 0):max(x1p, 0)] = pane
            if rng.random() < 0.5:  # curtains / blinds
                yc = int(y0 + (y1 - y0) * rng.uniform(0.2, 0.7))
                img[max(y0, 0):max(yc, 0), max(x0p, 0):max(x1p, 0)] = _rgb(rng, sat=(0, 0.5), val=(0.4, 0.9))
    shop_top = int(h - floor_h * sy * 0.9)
    x = 0
    while x < w:  # shop windows, doors and signs along the ground floor
        seg = int(rng.uniform(1.5, 5.0) * sx)
        kind = rng.random()
        if kind < 0.5:
            img[shop_top:h, x:x + seg - 2] = np.array([25, 35, 45], np.float32) + rng.uniform(0, 90)
        elif kind < 0.7:
            img[shop_top + int(0.25 * (h - shop_top)):h, x:x + max(2, seg // 3)] = _rgb(rng, val=(0.15, 0.5))
        sign_h = max(2, int(0.5 * sy))
        img[shop_top - sign_h:shop_top, x:x + seg - 2] = _rgb(rng)
        x += seg
    return _finish(img, rich)


def asphalt(rng: np.random.Generator, width_m: float, length_m: float, line_ys: list[float],
            dash_ys: list[float], px_per_m: float = 24.0, max_px: int = 512, rich: bool = True) -> np.ndarray:
    """Road top face: asphalt noise, patches, and lane markings.

    The image is laid out as the top face of a box: columns run along +x (length), rows from +y
    (row 0) to -y. `line_ys` are solid lines, `dash_ys` dashed lines, both in metres from the road
    centre (+y = left of the direction +x).
    """
    w = int(min(max_px, length_m * px_per_m))
    h = int(min(max_px, width_m * px_per_m))
    sx, sy = w / length_m, h / width_m
    gray = np.array([88, 88, 92], np.float32) * rng.uniform(0.85, 1.15)
    img = _shade(gray, value_noise(rng, h, w, octaves=7, base=6), 0.55)
    speck = rng.random((h, w)) < 0.03
    img[speck] *= rng.uniform(0.5, 1.6, size=(int(speck.sum()), 1)).astype(np.float32)
    _rects(img, rng, int(rng.integers(2, 6)), (0.05, 0.25), [gray * 0.75, gray * 1.2], 0.5)  # repairs

    def row(y_m: float) -> int:
        return int((width_m / 2 - y_m) * sy)

    paint = np.array([225, 225, 215], np.float32)
    lw = max(1, int(0.15 * sy))
    for y in line_ys:
        r = row(y)
        img[max(r - lw, 0):r + lw] = paint * rng.uniform(0.85, 1.0)
    dash, gap = 3.0, rng.uniform(5.0, 7.0)
    for y in dash_ys:
        r = row(y)
        x = rng.uniform(0, dash + gap)
        while x < length_m:
            img[max(r - lw, 0):r + lw, int(x * sx):int(min(x + dash, length_m) * sx)] = paint * rng.uniform(0.8, 1.0)
            x += dash + gap
    wear = value_noise(rng, h, w, octaves=4, base=16)
    img = img * (0.85 + 0.15 * wear[..., None])
    return _finish(img, rich)


def sidewalk(rng: np.random.Generator, width_m: float, length_m: float, px_per_m: float = 24.0,
             max_px: int = 512, rich: bool = True) -> np.ndarray:
    """Paving slabs with jittered joints and per-slab tint."""
    w = int(min(max_px, length_m * px_per_m))
    h = int(min(max_px, width_m * px_per_m))
    base = np.array([150, 146, 138], np.float32) * rng.uniform(0.85, 1.1)
    img = _shade(base, value_noise(rng, h, w, octaves=6, base=8), 0.4)
    joint = base * 0.55
    slab = rng.uniform(0.8, 1.4)
    xs = np.cumsum(rng.uniform(0.7, 1.3, size=int(length_m / slab * 1.5) + 2) * slab)
    ys = np.cumsum(rng.uniform(0.7, 1.3, size=int(width_m / slab * 1.5) + 2) * slab)
    for x in xs[xs < length_m]:
        c = int(x * w / length_m)
        img[:, max(c - 1, 0):c + 1] = joint
    for y in ys[ys < width_m]:
        r = int(y * h / width_m)
        img[max(r - 1, 0):r + 1] = joint
    tint = cv2.resize(rng.uniform(0.85, 1.15, size=(len(ys), len(xs))).astype(np.float32), (w, h),
                      interpolation=cv2.INTER_NEAREST)
    return _finish(img * tint[..., None], rich)


def bark(rng: np.random.Generator, size: int, rich: bool = True) -> np.ndarray:
    """Tree bark: vertical streaks of brown noise."""
    n = value_noise(rng, size, size // 4, octaves=5, base=4)
    n = cv2.resize(n, (size, size), interpolation=cv2.INTER_LINEAR)
    base = np.array([95, 70, 50], np.float32) * rng.uniform(0.8, 1.2)
    return _finish(_shade(base, n, 1.2), rich)


def foliage(rng: np.random.Generator, size: int, rich: bool = True) -> np.ndarray:
    """Leaves: green noise with light and dark blobs."""
    base = _rgb(rng, hue=rng.uniform(0.2, 0.35), sat=(0.4, 0.8), val=(0.3, 0.6))
    img = _shade(base, value_noise(rng, size, size, octaves=7, base=8), 1.3)
    return _finish(img, rich)


def metal(rng: np.random.Generator, size: int, rich: bool = True) -> np.ndarray:
    """Painted pole metal with scratches and stickers."""
    img = _shade(_rgb(rng, sat=(0, 0.3), val=(0.3, 0.7)), value_noise(rng, size, size, 5, 3), 0.6)
    _rects(img, rng, int(rng.integers(3, 8)), (0.05, 0.2))
    return _finish(img, rich)


def clothing(rng: np.random.Generator, size: int, rich: bool = True) -> np.ndarray:
    """Clothes: shirt colour over the upper half, trousers below, with a print pattern and creases."""
    top, bottom = _rgb(rng), _rgb(rng, sat=(0.1, 0.6), val=(0.15, 0.6))
    n = value_noise(rng, size, size, octaves=5, base=4)
    img = np.empty((size, size, 3), np.float32)
    img[: size // 2] = _shade(top, n[: size // 2], 0.7)
    img[size // 2:] = _shade(bottom, n[size // 2:], 0.7)
    if rng.random() < 0.5:  # stripes on the shirt
        period = int(rng.integers(4, max(5, size // 8)))
        rows = (np.arange(size // 2) // period) % 2 == 0
        img[: size // 2][rows] = img[: size // 2][rows] * 0.55
    _rects(img[: size // 2], rng, int(rng.integers(1, 4)), (0.1, 0.3))
    return _finish(img, rich)


def skin(rng: np.random.Generator, size: int, rich: bool = True) -> np.ndarray:
    """Head: skin tone, hair on top, face features as dark blobs."""
    tone = np.array([224, 172, 130], np.float32) * rng.uniform(0.45, 1.05)
    img = _shade(tone, value_noise(rng, size, size, 4, 3), 0.3)
    img[: size // 3] = _rgb(rng, sat=(0.2, 0.7), val=(0.05, 0.5))
    for cx in (0.35, 0.65):
        cv2.circle(img, (int(cx * size), int(0.5 * size)), max(1, size // 16), (30, 25, 20), -1)
    return _finish(img, rich)
