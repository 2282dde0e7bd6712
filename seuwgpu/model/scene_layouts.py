"""The three procedural scenes' layouts (fixed per scene name; `seed` never changes them): lists of
`Part`s (model/scene_parts.py). model/scenes.py registers them."""

from __future__ import annotations

import numpy as np

from seuwgpu.model.scene_parts import Noise, Part, normalize, smoothstep, surface_frame

# --------------------------------------------------------------------------------------------
# Scene layouts (fixed per scene name)
# --------------------------------------------------------------------------------------------

Z = np.array([0.0, 0.0, 1.0])
EYE3 = np.eye(3)

SPHERES_BASE_TOP = -0.42  # z of the platform top of the "spheres" scene (tests use it)


def layout_spheres() -> list[Part]:
    top, thick, rb = SPHERES_BASE_TOP, 0.12, 1.0
    noise = Noise(11, 3.0)
    parts = []

    def checker(ctx):
        p = ctx["pts"]
        cell = (np.floor(p[:, 0] / 0.25) + np.floor(p[:, 1] / 0.25)) % 2
        light, dark = np.array([0.80, 0.79, 0.74]), np.array([0.36, 0.42, 0.52])
        col = np.where(cell[:, None] > 0, light, dark)
        r = np.hypot(p[:, 0], p[:, 1])
        ring = smoothstep(0.035, 0.0, np.abs(r - 0.93))  # a dark ring near the rim
        return col * (1.0 - 0.6 * ring[:, None]) * (1.0 + 0.03 * noise(p))[:, None]

    parts.append(Part("base_top", "disk", [0, 0, top], EYE3, {"r0": 0.0, "r1": rb}, [0.6, 0.6, 0.6], texture=checker))
    parts.append(
        Part(
            "base_side",
            "frustum",
            [0, 0, top - thick],
            EYE3,
            {"r0": rb, "r1": rb, "h": thick, "flip": 0.0},
            [0.22, 0.23, 0.27],
            gloss=0.3,
        )
    )

    def marble(ctx):
        p = ctx["pts"]
        v = 0.5 + 0.5 * np.sin(9.0 * p[:, 0] + 4.0 * noise(p * 1.5))
        return ctx["colour"] * (0.7 + 0.45 * v[:, None])

    def gores(ctx):  # beach-ball stripes around the local pole
        lp = ctx["local"]
        k = np.floor(4.0 * (np.arctan2(lp[:, 1], lp[:, 0]) / np.pi + 1.0)) % 2
        white = np.array([0.95, 0.95, 0.93])
        col = np.where(k[:, None] > 0, ctx["colour"], white)
        cap = np.abs(ctx["uv"][:, 1]) > 0.93
        return np.where(cap[:, None], np.array([0.9, 0.85, 0.2]), col)

    def speckle(ctx):
        v = noise(ctx["pts"] * 4.0)
        return ctx["colour"] * (1.0 + 0.12 * v[:, None])

    tilt = surface_frame(normalize([0.3, -0.5, 1.0]))
    spheres = [  # name, centre xy, radius, colour, gloss, texture, frame
        ("red", (0.35, -0.25), 0.40, (0.85, 0.14, 0.12), 1.0, speckle, EYE3),
        ("blue", (-0.45, -0.35), 0.28, (0.14, 0.32, 0.85), 0.3, gores, tilt),
        ("yellow", (-0.08, 0.14), 0.17, (0.95, 0.78, 0.12), 0.5, speckle, EYE3),
        ("green", (0.55, 0.45), 0.24, (0.22, 0.68, 0.36), 0.6, marble, EYE3),
    ]
    for name, (x, y), r, col, gloss, tex, fr in spheres:
        parts.append(Part(name, "sphere", [x, y, top + r], fr, {"r": r}, col, gloss=gloss, texture=tex))
    # a small magenta sphere resting on top of the red one
    parts.append(
        Part(
            "magenta",
            "sphere",
            [0.35, -0.25, top + 0.80 + 0.15],
            EYE3,
            {"r": 0.15},
            [0.80, 0.25, 0.65],
            gloss=0.5,
            texture=speckle,
        )
    )
    # a gold torus standing upright
    R, r = 0.28, 0.085
    axis = normalize([1.0, -1.0, 0.0])
    parts.append(
        Part(
            "torus",
            "torus",
            [-0.42, 0.42, top + R + r],
            surface_frame(axis, Z),
            {"R": R, "r": r},
            [0.92, 0.66, 0.22],
            gloss=1.0,
            texture=speckle,
        )
    )
    return parts


BLOCKS_PITCH = 0.16
BLOCKS_PLATE = 0.064
BLOCKS_BRICK = 0.192
_LEGO = np.array(
    [
        [0.78, 0.10, 0.10],
        [0.05, 0.34, 0.75],
        [0.98, 0.80, 0.10],
        [0.14, 0.55, 0.22],
        [0.95, 0.95, 0.93],
        [0.12, 0.12, 0.14],
        [0.95, 0.50, 0.10],
        [0.55, 0.75, 0.90],
        [0.62, 0.64, 0.66],
        [0.45, 0.25, 0.15],
        [0.80, 0.35, 0.60],
        [0.60, 0.80, 0.20],
    ]
)


def _brick_grid(nx=10, layers=5):
    """Random stacked bricks on a plate: an id per voxel (-1 empty; 0 = the base plate)."""
    rng = np.random.default_rng(20240611)
    occ = -np.ones((nx, nx, layers + 1), dtype=np.int64)
    occ[:, :, 0] = 0
    colours = [np.array([0.25, 0.55, 0.30])]
    sizes = [(2, 4), (2, 3), (2, 2), (1, 4), (1, 3), (1, 2), (2, 6), (1, 1)]
    next_id = 1
    for z in range(1, layers + 1):
        lo, hi = (1, nx - 1) if z == 1 else (1 + (z - 1) // 2, nx - 1 - (z - 1) // 2)
        tries = 220 if z == 1 else 160
        for _ in range(tries):
            a, b = sizes[rng.integers(len(sizes))]
            if rng.random() < 0.5:
                a, b = b, a
            x0 = rng.integers(lo, max(lo + 1, hi - a + 1))
            y0 = rng.integers(lo, max(lo + 1, hi - b + 1))
            if x0 + a > hi or y0 + b > hi:
                continue
            cells = occ[x0 : x0 + a, y0 : y0 + b, z]
            below = occ[x0 : x0 + a, y0 : y0 + b, z - 1]
            if np.any(cells >= 0) or np.mean(below >= 0) < (1.0 if z == 1 else 0.6):
                continue
            occ[x0 : x0 + a, y0 : y0 + b, z] = next_id
            colours.append(_LEGO[rng.integers(len(_LEGO))] * (0.92 + 0.16 * rng.random()))
            next_id += 1
    return occ, np.array(colours)


def layout_blocks() -> list[Part]:
    occ, brick_col = _brick_grid()
    nx, ny, nz = occ.shape
    p = BLOCKS_PITCH
    z_edges = np.concatenate([[0.0], BLOCKS_PLATE + BLOCKS_BRICK * np.arange(nz)]) - 0.55
    x_edges = (np.arange(nx + 1) - nx / 2) * p
    padded = -np.ones((nx + 2, ny + 2, nz + 2), dtype=np.int64)
    padded[1:-1, 1:-1, 1:-1] = occ

    def nb(ix, iy, iz, d):
        return padded[ix + 1 + d[0], iy + 1 + d[1], iz + 1 + d[2]]

    ix, iy, iz = np.nonzero(occ >= 0)
    ids = occ[ix, iy, iz]
    cx = 0.5 * (x_edges[ix] + x_edges[ix + 1])
    cy = 0.5 * (x_edges[iy] + x_edges[iy + 1])
    z0, z1 = z_edges[iz], z_edges[iz + 1]
    cz = 0.5 * (z0 + z1)
    hz = 0.5 * (z1 - z0)
    origins, frames, hx, hy, flags, cols = [], [], [], [], [], []
    dirs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1)]  # bottoms are never seen
    for d in dirs:
        d = np.array(d)
        free = nb(ix, iy, iz, d) < 0
        if not np.any(free):
            continue
        n = d.astype(np.float64)
        if d[2] != 0:
            e1 = np.array([1.0, 0.0, 0.0])
            half = (np.full(free.sum(), p / 2), np.full(free.sum(), p / 2))
            o = np.stack([cx, cy, z1], axis=1)[free]
        else:
            e1 = np.cross(Z, n)  # horizontal tangent; e2 = n x e1 = +z
            half = (np.full(free.sum(), p / 2), hz[free])
            o = np.stack([cx + n[0] * p / 2, cy + n[1] * p / 2, cz], axis=1)[free]
        fr = surface_frame(n, e1)
        e2 = fr[:, 1]
        # seams: flag the face edges where the neighbouring voxel belongs to another brick
        fl = []
        for e in (-e1, e1, -e2, e2):
            di = np.rint(e).astype(int)
            fl.append(nb(ix[free], iy[free], iz[free], di) != ids[free])
        origins.append(o)
        frames.append(np.broadcast_to(fr, (o.shape[0], 3, 3)))
        hx.append(half[0])
        hy.append(half[1])
        flags.append(np.stack(fl, axis=1))
        cols.append(brick_col[ids[free]])
    flags = np.concatenate(flags).astype(np.float64)
    noise = Noise(23, 6.0)

    def seams(ctx):
        uv = ctx["uv"]
        f = flags[ctx["inst"]]
        dist = np.stack([uv[:, 0] + 1.0, 1.0 - uv[:, 0], uv[:, 1] + 1.0, 1.0 - uv[:, 1]], axis=1)
        dist = dist * np.stack([ctx["p"]["hx"], ctx["p"]["hx"], ctx["p"]["hy"], ctx["p"]["hy"]], axis=1)
        edge = np.max(f * smoothstep(0.012, 0.0, dist), axis=1)
        return ctx["colour"] * (1.0 - 0.55 * edge)[:, None] * (1.0 + 0.03 * noise(ctx["pts"]))[:, None]

    parts = [
        Part(
            "faces",
            "quad",
            np.concatenate(origins),
            np.concatenate(frames),
            {"hx": np.concatenate(hx), "hy": np.concatenate(hy)},
            np.concatenate(cols),
            gloss=0.6,
            texture=seams,
        )
    ]
    # studs on every free top
    top_free = nb(ix, iy, iz, (0, 0, 1)) < 0
    so = np.stack([cx, cy, z1], axis=1)[top_free]
    sc = brick_col[ids[top_free]]
    rs, hs = 0.3 * p, 0.034
    parts.append(
        Part(
            "stud_sides",
            "frustum",
            so,
            EYE3,
            {"r0": rs, "r1": rs, "h": hs, "flip": 0.0},
            sc * 0.9,
            gloss=0.8,
            cap=[0.5 * hs, np.inf],
        )
    )
    parts.append(
        Part(
            "stud_tops",
            "disk",
            so + [0.0, 0.0, hs],
            EYE3,
            {"r0": 0.0, "r1": rs},
            sc,
            gloss=0.6,
            texture=lambda ctx: ctx["colour"] * (1.0 - 0.25 * smoothstep(0.75, 1.0, ctx["uv"][:, 0]))[:, None],
        )
    )
    return parts


PLANT_SOIL = -0.52


def layout_plant() -> list[Part]:
    rng = np.random.default_rng(77)
    noise = Noise(31, 4.0)
    parts = []
    zb, zt, rbot, rtop = -1.0, -0.45, 0.30, 0.42
    band = Noise(5, 8.0)

    def terracotta(ctx):
        z = ctx["pts"][:, 2]
        stripe = smoothstep(0.012, 0.0, np.abs(z - (zt - 0.09)))  # a darker groove below the rim
        return ctx["colour"] * (1.0 - 0.35 * stripe[:, None]) * (1.0 + 0.05 * band(ctx["pts"]))[:, None]

    parts.append(
        Part(
            "pot",
            "frustum",
            [0, 0, zb],
            EYE3,
            {"r0": rbot, "r1": rtop, "h": zt - zb, "flip": 0.0},
            [0.74, 0.38, 0.22],
            texture=terracotta,
            gloss=0.2,
        )
    )
    rin = rbot + (rtop - rbot) * (PLANT_SOIL - zb) / (zt - zb) - 0.03
    parts.append(
        Part(
            "pot_inner",
            "frustum",
            [0, 0, PLANT_SOIL],
            EYE3,
            {"r0": rin, "r1": rtop - 0.03, "h": zt - PLANT_SOIL, "flip": 1.0},
            [0.55, 0.27, 0.16],
        )
    )
    parts.append(
        Part(
            "rim",
            "torus",
            [0, 0, zt],
            EYE3,
            {"R": rtop - 0.012, "r": 0.03},
            [0.78, 0.42, 0.25],
            texture=terracotta,
            gloss=0.3,
        )
    )

    def soil(ctx):
        v = noise(ctx["pts"] * 6.0)
        grit = np.sin(ctx["pts"][:, 0] * 173.0) * np.sin(ctx["pts"][:, 1] * 191.0)
        return ctx["colour"] * (1.0 + 0.25 * v + 0.15 * grit)[:, None]

    parts.append(
        Part(
            "soil",
            "disk",
            [0, 0, PLANT_SOIL],
            EYE3,
            {"r0": 0.0, "r1": rin},
            [0.26, 0.17, 0.11],
            texture=soil,
            weight=0.6,
        )
    )

    # stems and twigs: chains of tapering frusta; leaves at their upper nodes
    seg_o, seg_ax, seg_r0, seg_r1, seg_h = [], [], [], [], []
    leaf_nodes = []  # (position, branch direction)

    def grow(start, direction, length, nseg, r0, r1, droop, spawn):
        pos, d = np.array(start, float), normalize(direction)
        for i in range(nseg):
            h = length / nseg
            ra = r0 + (r1 - r0) * i / nseg
            rb = r0 + (r1 - r0) * (i + 1) / nseg
            seg_o.append(pos.copy())
            seg_ax.append(d.copy())
            seg_r0.append(ra)
            seg_r1.append(rb)
            seg_h.append(h)
            pos = pos + d * h
            horiz = normalize(d * [1, 1, 0] + 1e-6)
            d = normalize(d + droop * (horiz * 0.6 - Z * 0.4) + 0.12 * rng.standard_normal(3))
            frac = (i + 1) / nseg
            if frac > 0.35:
                leaf_nodes.append((pos.copy(), d.copy(), 3 + int(rng.integers(3))))
            if spawn and 0.3 < frac < 0.85 and rng.random() < 0.45:
                side = normalize(np.cross(d, Z) * (1 if rng.random() < 0.5 else -1) + 0.3 * d + 0.2 * Z)
                grow(pos, side, 0.22 + 0.18 * rng.random(), 4, rb * 0.8, 0.004, 0.35, False)

    nstem = 8
    for k in range(nstem):
        az = 2 * np.pi * k / nstem + 0.4 * rng.random()
        rad = 0.03 + 0.09 * rng.random()
        start = [rad * np.cos(az), rad * np.sin(az), PLANT_SOIL - 0.02]
        tilt = 0.08 + 0.3 * rng.random()
        direction = [np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
        grow(start, direction, 1.0 + 0.5 * rng.random(), 11, 0.02, 0.006, 0.05 + 0.06 * rng.random(), True)

    seg_ax = np.array(seg_ax)
    parts.append(
        Part(
            "stems",
            "frustum",
            np.array(seg_o),
            surface_frame(seg_ax),
            {"r0": np.array(seg_r0), "r1": np.array(seg_r1), "h": np.array(seg_h), "flip": 0.0},
            [0.36, 0.27, 0.15],
            weight=1.5,
            cap=np.stack([np.full(len(seg_r0), np.inf), 0.8 * np.array(seg_r1)], axis=1),
            texture=lambda ctx: ctx["colour"] * (1.0 + 0.15 * noise(ctx["pts"] * 5.0))[:, None],
        )
    )

    lo, le1, le3, ll, lw, lbend, lcurl, lcol = [], [], [], [], [], [], [], []
    for pos, d, count in leaf_nodes:
        for _ in range(count):
            az = 2 * np.pi * rng.random()
            side = normalize(np.cross(d, [np.cos(az), np.sin(az), 0.3]))
            droop = -0.2 + 0.9 * rng.random()
            e1 = normalize(side + 0.5 * d - droop * Z)
            e3 = normalize(Z - np.dot(Z, e1) * e1 + 0.35 * rng.standard_normal(3))
            lo.append(pos + 0.01 * side)
            le1.append(e1)
            le3.append(e3)
            ll.append(0.10 + 0.09 * rng.random())
            lw.append(0.022 + 0.02 * rng.random())
            lbend.append(-0.05 - 0.15 * rng.random())
            lcurl.append(-0.1 - 0.2 * rng.random())
            g = rng.random()
            lcol.append(np.array([0.10 + 0.18 * g, 0.36 + 0.28 * g, 0.08 + 0.10 * rng.random()]))
    lw = np.array(lw)

    def veins(ctx):
        s, t = ctx["uv"][:, 0], ctx["uv"][:, 1]
        rib = smoothstep(0.12, 0.0, np.abs(t)) * (1.0 - s)
        side_veins = 0.5 + 0.5 * np.cos(2 * np.pi * (7.0 * s - 2.5 * np.abs(t)))
        tip = smoothstep(0.7, 1.0, s)
        col = ctx["colour"] * (1.0 + 0.45 * rib - 0.10 * side_veins + 0.15 * tip)[:, None]
        return col + np.array([0.05, 0.06, 0.0]) * rib[:, None]

    e1 = np.array(le1)
    parts.append(
        Part(
            "leaves",
            "leaf",
            np.array(lo),
            surface_frame(np.array(le3), e1),
            {"l": np.array(ll), "w": lw, "bend": np.array(lbend), "curl": np.array(lcurl)},
            np.array(lcol),
            weight=2.0,
            gloss=0.7,
            cap=np.stack([0.4 * lw, 0.4 * lw], axis=1),
            texture=veins,
        )
    )
    return parts
