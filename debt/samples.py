# Sample images for DEBT's tests and benchmark, drawn procedurally so that the
# project ships no third-party pictures and every run sees the same pixels.
#
# Plan: a few primitives (fractal value noise, soft discs, shading) and three
# scenes built from them: a grey outdoor scene with sky, hills, a building,
# grass and a fence (edges, textures and gradients, like a photograph); a
# colour still life (saturated shaded balls on a striped cloth); and an
# underwater seabed (rippled sand, rocks, weed, caustics, blue-green haze).
# These are synthetic renderings, not photographs.

from __future__ import annotations

import numpy as np


def _value_noise(rng, h: int, w: int, cell: float) -> np.ndarray:
    # Random lattice values, bicubic-smoothstep interpolated: smooth noise
    # with features about `cell` pixels apart.
    gh, gw = int(h / cell) + 3, int(w / cell) + 3
    grid = rng.standard_normal((gh, gw))
    y = np.arange(h) / cell
    x = np.arange(w) / cell
    y0 = np.floor(y).astype(int)
    x0 = np.floor(x).astype(int)
    fy = y - y0
    fx = x - x0
    fy = fy * fy * (3 - 2 * fy)
    fx = fx * fx * (3 - 2 * fx)
    a = grid[y0][:, x0]
    b = grid[y0][:, x0 + 1]
    c = grid[y0 + 1][:, x0]
    d = grid[y0 + 1][:, x0 + 1]
    top = a + (b - a) * fx[None, :]
    bot = c + (d - c) * fx[None, :]
    return top + (bot - top) * fy[:, None]


def fractal_noise(rng, h: int, w: int, cell: float = 64.0, octaves: int = 6,
                  gain: float = 0.55) -> np.ndarray:
    """Sum of value-noise octaves (a 1/f-like texture), roughly unit variance."""
    out = np.zeros((h, w))
    amp = 1.0
    total = 0.0
    for _ in range(octaves):
        out += amp * _value_noise(rng, h, w, max(cell, 1.0))
        total += amp * amp
        amp *= gain
        cell /= 2.0
    return out / np.sqrt(total)


def _to_uint8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def natural_grey(height: int = 240, width: int = 320, seed: int = 1) -> np.ndarray:
    """A grey outdoor scene: sky, clouds, hills, a building, grass, a fence."""
    rng = np.random.default_rng(seed)
    h, w = height, width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    sy, sx = h / 240.0, w / 320.0
    # Sky: vertical gradient with soft clouds.
    img = 200 - 60 * (yy / h) + 18 * np.clip(fractal_noise(rng, h, w, 80 * sx, 5), 0, None)
    # Distant hills with a fractal ridge line, lit from the left.
    ridge = 95 * sy + 22 * sy * fractal_noise(rng, 1, w, 90 * sx, 6)[0]
    hills = yy > ridge[None, :]
    tex = fractal_noise(rng, h, w, 40 * sx, 6)
    img = np.where(hills, 120 + 14 * tex - 25 * (xx / w), img)
    # Near field: grass with fine texture, darker at the bottom.
    field_top = 160 * sy + 6 * sy * np.sin(xx[0] / (37 * sx))
    field = yy > field_top[None, :]
    grass = fractal_noise(rng, h, w, 6 * sx, 3, 0.7)
    strokes = np.sin(xx * 1.7 + 4 * fractal_noise(rng, h, w, 12 * sx, 2)) * 10
    img = np.where(field, 95 + 22 * grass + strokes - 30 * (yy - 160 * sy) / h, img)
    # A building: walls in two shades, a dark roof, rows of windows.
    bx0, bx1, by0, by1 = int(180 * sx), int(265 * sx), int(70 * sy), int(175 * sy)
    wall = (xx >= bx0) & (xx < bx1) & (yy >= by0) & (yy < by1)
    img = np.where(wall, np.where(xx < (bx0 + bx1) / 2, 170, 135) + 4 * tex, img)
    roof = (yy >= by0 - 30 * sy + np.abs(xx - (bx0 + bx1) / 2) * 0.55) & (yy < by0) & (xx >= bx0 - 6) & (xx < bx1 + 6)
    img = np.where(roof, 60 + 8 * tex, img)
    for r in range(3):
        for c in range(4):
            wx0 = bx0 + int((8 + 19 * c) * sx)
            wy0 = by0 + int((12 + 30 * r) * sy)
            win = (xx >= wx0) & (xx < wx0 + int(11 * sx)) & (yy >= wy0) & (yy < wy0 + int(16 * sy))
            img = np.where(win, 40 + 25 * (c % 2) + 3 * tex, img)
    # A tree: a dark textured crown on a trunk.
    trunk = (np.abs(xx - 70 * sx) < 5 * sx) & (yy > 110 * sy) & (yy < 185 * sy)
    img = np.where(trunk, 55 + 6 * tex, img)
    crown_r = 38 * sx * (1 + 0.18 * fractal_noise(rng, h, w, 10 * sx, 3))
    crown = (xx - 70 * sx) ** 2 + ((yy - 95 * sy) * 1.2) ** 2 < crown_r ** 2
    img = np.where(crown, 75 + 25 * fractal_noise(rng, h, w, 4 * sx, 3) - 0.25 * (xx - 70 * sx), img)
    # A fence in front: light posts and two rails, with shadows.
    for i in range(9):
        px = int((8 + 36 * i) * sx)
        post = (xx >= px) & (xx < px + 6 * sx) & (yy > 170 * sy) & (yy < 225 * sy)
        img = np.where(post, 205 - 40 * ((xx - px) / (6 * sx)), img)
        shadow = (xx >= px + 6 * sx) & (xx < px + 10 * sx) & (yy > 180 * sy) & (yy < 228 * sy)
        img = np.where(shadow, img * 0.6, img)
    for ry in (182, 205):
        rail = (yy > ry * sy) & (yy < (ry + 5) * sy)
        img = np.where(rail, 185 - 10 * np.sin(xx / 9.0), img)
    # Mild sensor noise, as a photograph would have.
    img += 2.0 * rng.standard_normal((h, w))
    return _to_uint8(img)


def _sphere(xx, yy, cx, cy, r, colour, light=(-0.5, -0.6)):
    dx = (xx - cx) / r
    dy = (yy - cy) / r
    d2 = dx * dx + dy * dy
    inside = d2 < 1.0
    dz = np.sqrt(np.clip(1 - d2, 0, 1))
    lx, ly = light
    lz = np.sqrt(max(0.0, 1 - lx * lx - ly * ly))
    diffuse = np.clip(dx * lx + dy * ly + dz * lz, 0, 1)
    spec = np.clip(dx * lx + dy * ly + dz * lz, 0, 1) ** 40
    shade = 0.25 + 0.75 * diffuse
    rgb = np.stack([c * shade + 230 * spec for c in colour], axis=-1)
    return inside, rgb


def colour_still_life(height: int = 240, width: int = 320, seed: int = 2) -> np.ndarray:
    """A colour still life: shaded balls on a striped cloth before a wall."""
    rng = np.random.default_rng(seed)
    h, w = height, width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    s = min(h / 240.0, w / 320.0)
    wall_tex = fractal_noise(rng, h, w, 30 * s, 5)
    img = np.stack([150 + 30 * (xx / w) + 6 * wall_tex,
                    135 + 10 * wall_tex,
                    110 - 20 * (xx / w) + 6 * wall_tex], axis=-1)
    table = yy > 130 * s + 0.05 * xx
    stripes = (np.floor((xx + 0.6 * yy) / (14 * s)) % 2)[..., None]
    cloth = np.where(stripes > 0, [[[40, 70, 160]]], [[[235, 230, 215]]]).astype(np.float64)
    cloth *= (0.75 + 0.25 * (yy / h))[..., None]
    cloth += 5 * fractal_noise(rng, h, w, 3 * s, 2)[..., None]
    img = np.where(table[..., None], cloth, img)
    balls = [(80, 150, 42, (220, 40, 30)), (170, 165, 36, (240, 200, 30)),
             (250, 140, 46, (40, 160, 60)), (130, 200, 22, (150, 60, 180))]
    for cx, cy, r, col in balls:
        inside, rgb = _sphere(xx, yy, cx * s, cy * s, r * s, col)
        shadow = ((xx - cx * s - 0.5 * r * s) ** 2 / 1.6 + (yy - cy * s - 0.9 * r * s) ** 2 * 3
                  < (r * s) ** 2) & ~inside
        img = np.where(shadow[..., None], img * 0.55, img)
        img = np.where(inside[..., None], rgb, img)
    # A small chequered card with sharp edges.
    card = (xx > 20 * s) & (xx < 60 * s) & (yy > 40 * s) & (yy < 90 * s)
    check = ((np.floor(xx / (5 * s)) + np.floor(yy / (5 * s))) % 2)[..., None]
    img = np.where(card[..., None], np.where(check > 0, 20.0, 240.0), img)
    img += 1.5 * rng.standard_normal((h, w, 3))
    return _to_uint8(img)


def seabed(height: int = 240, width: int = 320, seed: int = 3) -> np.ndarray:
    """An underwater seabed: rippled sand, rocks, weed, caustics, blue-green haze."""
    rng = np.random.default_rng(seed)
    h, w = height, width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    s = min(h / 240.0, w / 320.0)
    warp = fractal_noise(rng, h, w, 50 * s, 4)
    # Perspective: ripples get finer towards the top (farther away).
    depth = 0.35 + 0.65 * (yy / h)
    ripples = np.sin((yy / depth) / (7.0 * s) + 2.5 * warp + 0.02 * xx)
    grain = fractal_noise(rng, h, w, 2 * s, 2)
    sand = 150 + 18 * ripples + 10 * fractal_noise(rng, h, w, 25 * s, 5) + 6 * grain
    img = np.stack([sand * 0.95, sand * 0.9, sand * 0.72], axis=-1)
    # Rocks: lumpy shaded blobs with a cast shadow.
    for cx, cy, r in [(70, 170, 34), (215, 190, 46), (280, 110, 22), (140, 95, 16)]:
        cx, cy, r = cx * s, cy * s, r * s
        lump = r * (1 + 0.25 * fractal_noise(rng, h, w, 8 * s, 3))
        dist = np.sqrt((xx - cx) ** 2 + ((yy - cy) * 1.5) ** 2)
        inside = dist < lump
        shade = np.clip(1.0 - (yy - cy + 0.6 * (xx - cx)) / (2.2 * r), 0.35, 1.2)
        rock = (70 + 25 * fractal_noise(rng, h, w, 3 * s, 3)) * shade
        shadow = (np.sqrt((xx - cx - 0.6 * r) ** 2 + ((yy - cy - 0.5 * r) * 2.0) ** 2) < r) & ~inside
        img = np.where(shadow[..., None], img * 0.6, img)
        img = np.where(inside[..., None], np.stack([rock * 0.8, rock * 0.85, rock * 0.75], -1), img)
    # Weed: a few wavy dark-green strands.
    for i in range(7):
        bx = (30 + 45 * i + 10 * rng.standard_normal()) * s
        base = (200 + 25 * rng.random()) * s
        length = (60 + 50 * rng.random()) * s
        t = np.clip((base - yy) / length, 0, 1)
        centre = bx + 10 * s * np.sin(yy / (11 * s) + i) * t
        strand = (np.abs(xx - centre) < 2.5 * s * (1.2 - t)) & (yy < base) & (yy > base - length)
        img = np.where(strand[..., None], [[[40, 95, 45]]], img)
    # Caustics: bright net of ridged noise, stronger near the camera.
    net = 1 - np.abs(fractal_noise(rng, h, w, 18 * s, 3))
    img = img + (35 * np.clip(net - 0.55, 0, None) * depth)[..., None]
    # Water: attenuation of red, blue-green veil, more with distance.
    far = 1 - yy / h
    veil = np.array([20.0, 95.0, 115.0])
    img = img * np.array([0.45, 0.8, 0.9])
    mix = (0.25 + 0.55 * far)[..., None]
    img = img * (1 - mix) + veil * mix
    # Vignetting of the lamp and sensor noise.
    r2 = ((xx - w / 2) / w) ** 2 + ((yy - h / 2) / h) ** 2
    img = img * (1.05 - 0.8 * r2)[..., None]
    img += 2.0 * rng.standard_normal((h, w, 3))
    return _to_uint8(img)


SAMPLES = {
    "grey-scene": natural_grey,
    "colour-still-life": colour_still_life,
    "seabed": seabed,
}


def sample(name: str, height: int = 240, width: int = 320) -> np.ndarray:
    """One of the SAMPLES by name, at the given size."""
    try:
        make = SAMPLES[name]
    except KeyError:
        raise ValueError(f"unknown sample {name!r}; choose from {', '.join(SAMPLES)}") from None
    return make(height, width)

