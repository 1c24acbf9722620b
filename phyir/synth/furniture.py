"""Furniture of the synthetic rooms, built from primitives: each maker returns (name, OBB half sizes,
parts, against wall, top height, base y) for a palette."""

from __future__ import annotations


def _legs(w, d, h, r, m, inset=0.05, cyl=False):
    out = []
    for sx in (-1, 1):
        for sz in (-1, 1):
            c = (sx * (w / 2 - inset), h / 2, sz * (d / 2 - inset))
            out.append(("cyl", c, (r, h / 2), m) if cyl else ("box", c, (r, h / 2, r), m))
    return out


def bed(rng, pal):
    w = float(rng.choice([0.95, 1.4, 1.6, 1.8])) + float(rng.uniform(-0.05, 0.05))
    L = float(rng.uniform(1.95, 2.1))
    frame = pal.wood() if rng.random() < 0.6 else pal.fabric()
    sheet, blanket, pillow = pal.fabric(), pal.fabric(), pal.fabric()
    hb = float(rng.uniform(0.8, 1.1))
    parts = [("box", (0, 0.15, 0), (w / 2, 0.15, L / 2), frame),
             ("box", (0, 0.4, 0.02), (w / 2 - 0.03, 0.1, L / 2 - 0.06), sheet),
             ("box", (0, 0.44, -L * 0.15), (w / 2 - 0.01, 0.075, L * 0.33), blanket),
             ("box", (0, hb / 2, L / 2 - 0.03), (w / 2, hb / 2, 0.03), frame)]
    n_p = 1 if w < 1.2 else 2
    for k in range(n_p):
        x = 0 if n_p == 1 else (k - 0.5) * w / 2
        pw = min(0.3, w / 4 - 0.02) if n_p == 2 else 0.3
        parts.append(("box", (x, 0.55, L / 2 - 0.3), (pw, 0.06, 0.18), pillow))
    return "bed", (w / 2, hb / 2, L / 2), parts, True, None, 0.0


def table(rng, pal):
    w, d = float(rng.uniform(0.8, 1.8)), float(rng.uniform(0.6, 0.95))
    h = float(rng.uniform(0.7, 0.77))
    top = pal.wood(glossy=rng.random() < 0.5) if rng.random() < 0.6 else pal.plastic()
    legm = pal.metal() if rng.random() < 0.4 else top
    parts = [("box", (0, h - 0.02, 0), (w / 2, 0.02, d / 2), top)]
    parts += _legs(w, d, h - 0.04, 0.025, legm, cyl=rng.random() < 0.5)
    return "table", (w / 2, h / 2, d / 2), parts, rng.random() < 0.4, h, 0.0


def shelf(rng, pal):
    w, d, h = float(rng.uniform(0.6, 1.2)), float(rng.uniform(0.28, 0.4)), float(rng.uniform(1.4, 2.1))
    m = pal.wood() if rng.random() < 0.6 else pal.plastic(glossy=False)
    t = 0.02
    parts = [("box", (-w / 2 + t, h / 2, 0), (t, h / 2, d / 2), m),
             ("box", (w / 2 - t, h / 2, 0), (t, h / 2, d / 2), m),
             ("box", (0, h / 2, d / 2 - 0.005), (w / 2 - 2 * t, h / 2, 0.005), m)]
    n = int(rng.integers(3, 6))
    for k in range(n + 1):
        y = t + k * (h - 2 * t) / n
        parts.append(("box", (0, y, 0), (w / 2 - 2 * t, t, d / 2 - 0.01), m))
        if k < n and rng.random() < 0.7:  # a row of books
            x = -w / 2 + 3 * t
            while x < w / 2 - 0.15 and rng.random() < 0.85:
                bw = float(rng.uniform(0.02, 0.05))
                bh = float(rng.uniform(0.15, min(0.3, (h - 2 * t) / n - 0.05)))
                cover = pal.plastic() if rng.random() < 0.5 else pal.fabric()
                parts.append(("box", (x + bw / 2, y + t + bh / 2, -0.01),
                              (bw / 2 - 0.002, bh / 2, d / 2 - 0.05), cover))
                x += bw
    return "shelf", (w / 2, h / 2, d / 2), parts, True, None, 0.0


def cabinet(rng, pal):
    w, d, h = float(rng.uniform(0.5, 1.6)), float(rng.uniform(0.4, 0.6)), float(rng.uniform(0.6, 1.0))
    body = pal.wood() if rng.random() < 0.5 else pal.plastic()
    topm = pal.plastic(glossy=True) if rng.random() < 0.4 else body
    handle = pal.metal()
    parts = [("box", (0, (h - 0.03) / 2, 0), (w / 2 - 0.01, (h - 0.03) / 2, d / 2 - 0.01), body),
             ("box", (0, h - 0.015, 0), (w / 2, 0.015, d / 2), topm)]
    n = max(1, int(w / 0.45))
    for k in range(n):
        x = -w / 2 + (k + 0.5) * w / n
        parts.append(("box", (x, h * 0.75, -d / 2 + 0.005), (0.06, 0.008, 0.006), handle))
    return "cabinet", (w / 2, h / 2, d / 2), parts, rng.random() < 0.8, h, 0.0


def sofa(rng, pal):
    w, d = float(rng.uniform(1.5, 2.4)), float(rng.uniform(0.8, 1.0))
    m, cush = pal.fabric(), pal.fabric()
    arm = 0.15
    parts = [("box", (0, 0.2, 0), (w / 2, 0.2, d / 2), m),
             ("box", (0, 0.45, d / 2 - 0.1), (w / 2, 0.45, 0.1), m),
             ("box", (-w / 2 + arm / 2, 0.32, -0.1), (arm / 2, 0.32, d / 2 - 0.1), m),
             ("box", (w / 2 - arm / 2, 0.32, -0.1), (arm / 2, 0.32, d / 2 - 0.1), m)]
    n = int(rng.integers(2, 4))
    cw = (w - 2 * arm) / n
    for k in range(n):
        x = -w / 2 + arm + (k + 0.5) * cw
        parts.append(("box", (x, 0.46, -0.08), (cw / 2 - 0.01, 0.06, d / 2 - 0.14), cush))
    return "sofa", (w / 2, 0.45, d / 2), parts, rng.random() < 0.7, None, 0.0


def rug(rng, pal):
    w, d = float(rng.uniform(1.0, 2.5)), float(rng.uniform(0.7, 1.8))
    parts = [("box", (0, 0.005, 0), (w / 2, 0.005, d / 2), pal.fabric())]
    return "rug", (w / 2, 0.005, d / 2), parts, False, None, 0.0


def mirror(rng, pal):
    w, h = float(rng.uniform(0.4, 1.1)), float(rng.uniform(0.6, 1.4))
    y0 = float(rng.uniform(0.9, 1.1))
    frame = pal.wood() if rng.random() < 0.5 else pal.metal(brushed=True)
    parts = [("box", (0, h / 2, 0.01), (w / 2 + 0.03, h / 2 + 0.03, 0.01), frame),
             ("box", (0, h / 2, 0.0), (w / 2, h / 2, 0.015), pal.metal(mirror=True))]
    return "mirror", (w / 2 + 0.03, h / 2 + 0.03, 0.02), parts, True, None, y0 - 0.03


def art(rng, pal):
    w, h = float(rng.uniform(0.4, 1.2)), float(rng.uniform(0.3, 0.9))
    y0 = float(rng.uniform(1.1, 1.5))
    canvas = pal.fabric() if rng.random() < 0.5 else pal.ceramic()
    frame = pal.wood() if rng.random() < 0.5 else pal.metal()
    parts = [("box", (0, h / 2, 0.01), (w / 2, h / 2, 0.01), frame),
             ("box", (0, h / 2, 0.0), (w / 2 - 0.03, h / 2 - 0.03, 0.0125), canvas)]
    return "art", (w / 2, h / 2, 0.0125), parts, True, None, y0


def vase(rng, pal):
    r, h = float(rng.uniform(0.05, 0.12)), float(rng.uniform(0.15, 0.45))
    m = pal.ceramic() if rng.random() < 0.6 else pal.metal()
    parts = [("cyl", (0, h / 2, 0), (r, h / 2), m)]
    if rng.random() < 0.5:
        parts.append(("sph", (0, h + r * 0.6, 0), (r * 0.8,), m))
        h = h + r * 1.4
    return "vase", (r, h / 2, r), parts


def ball(rng, pal):
    r = float(rng.uniform(0.05, 0.14))
    m = pal.metal(mirror=rng.random() < 0.4) if rng.random() < 0.7 else pal.ceramic()
    return "ball", (r, r, r), [("sph", (0, r, 0), (r,), m)]
