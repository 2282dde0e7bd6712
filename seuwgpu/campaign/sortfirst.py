"""Sort-first rendering over Ray ranks: screen regions rendered by separate Ray actors, and the
ranks a corrupted primitive contaminates (see campaign/ray.py for the Ray set-up)."""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from seuwgpu.campaign.ray import get_ray, init_ray, worker_gpu
from seuwgpu.gpu.constants import TILE
from seuwgpu.metrics.image import changed_pixels
from seuwgpu.render.regions import region_grid, region_rects

# ---- sort-first rendering ---------------------------------------------------------------------


def split_regions(ranks: int, width: int, height: int) -> tuple[list[tuple[int, int, int, int]], tuple[int, int]]:
    """Tile-aligned regions (x0, y0, w, h), row-major, and the grid (px, py): the one grid of
    `render.regions`, which the contamination analysis uses too."""
    if ranks < 1:
        raise ValueError("--ranks must be at least 1")
    rows, cols = region_grid(ranks, height, width)
    return region_rects(ranks, height, width), (cols, rows)


class RankRenderer:
    """One rank of the sort-first renderer (a Ray actor): its own device, its own copy of the
    model, its region of every view, and the node-local guard."""

    def __init__(self, model, cameras, precision: str, viewport, rank: int = 0, guard_variant: str = "guard"):
        from seuwgpu.faults.guard import component_mask, guard_fields, stored_box
        from seuwgpu.render.renderer import Renderer

        t0 = time.perf_counter()
        self.rank, self.model, self.cameras, self.precision = rank, model, cameras, precision
        self.gpu = worker_gpu()
        self.r = Renderer(model, cameras, precision, gpu=self.gpu, viewport=viewport)
        self.box = stored_box(self.r.layout, self.r.clean_words, precision)
        self.guard_fields = guard_fields(guard_variant)
        self.mask = component_mask(self.guard_fields, model.sh_degree)
        self.r.set_guard(self.box.rows(), 0)
        self.clean = self.r.render()  # also the warm-up
        self.setup_s = time.perf_counter() - t0

    def info(self) -> dict:
        import socket

        return {
            "rank": self.rank,
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "viewport": self.r.viewport,
            "adapter": str(self.gpu.info.get("device")),
            "setup_s": self.setup_s,
        }

    def clean_image(self) -> np.ndarray:
        return self.clean

    def render(self) -> tuple[np.ndarray, float]:
        t0 = time.perf_counter()
        img = self.r.render()
        return img, time.perf_counter() - t0

    def time_render(self, repeats: int = 3) -> list[float]:
        return [self.render()[1] for _ in range(max(1, repeats))]

    def _flip(self, site):
        from seuwgpu.faults.flips import Flips
        from seuwgpu.faults.sites import mask_of

        ch, word, shift = self.r.layout.locate([site.primitive], [site.flat_component()])
        pairs = np.array([[int(word[0]), (mask_of(site.bits) << int(shift[0])) & 0xFFFFFFFF]], np.uint32)
        Flips(self.gpu, self.r.chunks).apply({int(ch[0]): pairs})

    def _restore(self):
        for c, words in enumerate(self.r.clean_words):
            self.gpu.write(self.r.chunks[c], words)

    def _measure(self, img, seconds, clamps=0) -> dict:
        ch = changed_pixels(img, self.clean)
        with np.errstate(invalid="ignore"):
            peak = float(np.nanmax(np.abs(img.astype(np.float64) - self.clean))) if img.size else 0.0
        return {
            "changed": int(ch.sum()),
            "pixels": int(ch.size),
            "peak_error": peak,
            "nonfinite": bool((~np.isfinite(img)).any()),
            "clamps": int(clamps),
            "seconds": seconds,
        }

    def contamination(self, site, guard: str = "scrub") -> dict:
        """The upset on this rank's copy: this rank's pixels without and with the node-local guard."""
        from seuwgpu.faults.guard import scrub

        out = {}
        self._flip(site)
        try:
            img, s = self.render()
            out["none"] = self._measure(img, s)
            t0 = time.perf_counter()
            if guard == "scrub":
                counts = scrub(self.r, self.box, self.guard_fields)
                img = self.r.render()
                clamps = sum(counts.values())
            elif guard == "clamp":
                self.r.set_guard(None, self.mask)
                self.r.reset_guard_counts()
                try:
                    img = self.r.render()
                    clamps = int(self.r.read_guard_counts().sum())
                finally:
                    self.r.set_guard(None, 0)
            else:
                raise ValueError(f"unknown guard mode {guard!r}; expected scrub or clamp")
            out["guard"] = self._measure(img, time.perf_counter() - t0, clamps)
        finally:
            self._restore()  # exact: the clean words (also undoes a scrub's repair of the flipped word)
        return out

    def worst_primitive(self, field: str, component: int, bits, sample: int, seed: int) -> int:
        """Most harmful primitive of a sample (full-frame footprint), as `seuwgpu inject` picks it."""
        from seuwgpu.faults.engine import Engine

        eng = Engine(self.model, self.cameras, self.precision, gpu=self.gpu)
        prim, _ = eng.worst_primitive(field, component, bits, sample=sample, seed=seed)
        return prim


def footprint_mask(values: np.ndarray, degree: int, cam) -> np.ndarray:
    """[H, W] bool: the pixels one primitive (flat stored values [ncomp]) contributes to in this
    view by the compositing rule, occlusion aside: inside its binned tile rectangle, sigma >= 0
    and alpha >= 1/255 (a NaN alpha contributes, as in the renderer). float32, as the numpy twin."""
    from seuwgpu.model.fields import Model
    from seuwgpu.render.composite import ALPHA_MAX, ALPHA_MIN
    from seuwgpu.render.project import F, project

    m = Model.from_flat(np.asarray(values, np.float32).reshape(1, -1), degree)
    p = project(m, cam)
    mask = np.zeros((cam.height, cam.width), bool)
    if not p["visible"][0]:
        return mask
    x0, y0, x1, y1 = (int(v) for v in p["rect"][0])
    xa, xb = x0 * TILE, min(x1 * TILE, cam.width)
    ya, yb = y0 * TILE, min(y1 * TILE, cam.height)
    if xa >= xb or ya >= yb:
        return mask
    px = np.arange(xa, xb, dtype=F) + F(0.5)
    py = np.arange(ya, yb, dtype=F) + F(0.5)
    mx, my = p["proj_xy"][0]
    cxx, cxy, czz = p["conic"][0]
    with np.errstate(all="ignore"):
        dx = (mx - px)[None, :]
        dy = (my - py)[:, None]
        sigma = F(0.5) * ((cxx * dx) * dx + (czz * dy) * dy) + (cxy * dx) * dy
        alpha = np.minimum(ALPHA_MAX, p["opacity"][0] * np.exp(-sigma))
        mask[ya:yb, xa:xb] = ~((sigma < 0) | (alpha < ALPHA_MIN))
    return mask


def footprint_reach(values: np.ndarray, degree: int, cameras, regions) -> set[int]:
    """Ranks whose region holds a pixel of the primitive's footprint (`footprint_mask`) in some view."""
    reach = set()
    for cam in cameras:
        fm = footprint_mask(values, degree, cam)
        for r, (x0, y0, w, h) in enumerate(regions):
            if fm[y0 : y0 + h, x0 : x0 + w].any():
                reach.add(r)
    return reach


def parse_upset(text: str) -> tuple[str, tuple[int, ...]]:
    """'field:bit' or 'field:bit,bit' -> (canonical field, bits)."""
    from seuwgpu.model.fields import canonical_field

    try:
        field, bits = text.split(":")
        return canonical_field(field.strip()), tuple(int(b) for b in bits.split(","))
    except ValueError as e:
        raise ValueError(f"--upset must look like log_scales:31 (field:bit), got {text!r} ({e})") from None


def check_upset(model, upset, primitive, component: int, precision: str):
    """Refuse a bad field, component, bit or primitive before Ray starts (it was a rank's remote
    traceback, after every rank had started)."""
    if upset is not None:
        from seuwgpu.faults.sites import make_site

        make_site(model, upset[0], 0 if primitive is None else primitive, component, upset[1], precision)


def sort_first(
    model,
    cameras,
    precision: str = "fp32",
    ranks: int = 4,
    upset=None,
    component: int = 0,
    primitive: int | None = None,
    sample: int = 32,
    seed: int = 0,
    guard: str = "scrub",
    repeats: int = 3,
    address: str | None = None,
    composite: bool = True,
    guard_variant: str = "guard",
) -> dict:
    """Render `cameras` with `ranks` Ray actors (sort-first), time the ranks, and (with `upset` =
    (field, bits)) find the ranks a single upset contaminates without and with the node-local guard
    (`guard_variant`: a pipeline guard, faults/defenses.py pipeline_guards, e.g. guard_all)."""
    ray = get_ray()
    from seuwgpu.faults.guard import clamp_values, component_mask, guard_fields, support_box
    from seuwgpu.faults.sites import make_site
    from seuwgpu.model import encoding
    from seuwgpu.model.budget import check_model
    from seuwgpu.render.renderer import check_cameras

    width, height = check_cameras(cameras)
    # each rank holds a renderer and a decoded copy, the driver the model and Ray's copy of it
    check_model(model.n, model.sh_degree, "a model of", "render sort-first")
    regions, grid = split_regions(ranks, width, height)
    check_upset(model, upset, primitive, component, precision)
    guarded_fields = guard_fields(guard_variant)  # an unknown variant refused before Ray starts
    started = init_ray(address)
    actors = []
    try:
        gpus = int(ray.cluster_resources().get("GPU", 0))
        opts = {"num_gpus": min(1.0, gpus / ranks)} if gpus else {}
        Actor = ray.remote(RankRenderer)
        mref = ray.put(model)
        t0 = time.perf_counter()
        actors = [
            Actor.options(**opts).remote(mref, cameras, precision, vp, r, guard_variant) for r, vp in enumerate(regions)
        ]
        infos = ray.get([a.info.remote() for a in actors])
        setup_wall = time.perf_counter() - t0
        out = {
            "ranks": ranks,
            "grid": grid,
            "regions": regions,
            "width": width,
            "height": height,
            "views": len(cameras),
            "n": model.n,
            "precision": precision,
            "infos": infos,
            "setup_wall_s": setup_wall,
            "guard_mode": guard,
            "guard_variant": guard_variant,
        }
        if composite:
            parts = ray.get([a.clean_image.remote() for a in actors])
            img = np.zeros((len(cameras), height, width, 3), np.float32)
            for (x0, y0, w, h), part in zip(regions, parts):
                img[:, y0 : y0 + h, x0 : x0 + w] = part
            out["composite"] = img
        times = [statistics.median(ray.get(a.time_render.remote(repeats))) for a in actors]  # one rank at a time
        t0 = time.perf_counter()
        ray.get([a.render.remote() for a in actors])  # a concurrent frame
        out["frame_wall_s"] = time.perf_counter() - t0
        out["times"] = times
        out["slowest"] = int(np.argmax(times))
        out["imbalance"] = float(max(times) / (sum(times) / len(times)))
        if upset is not None:
            field, bits = upset
            if primitive is None:
                primitive = ray.get(actors[0].worst_primitive.remote(field, component, bits, sample, seed))
                out["primitive_chosen"] = f"most harmful of {min(sample, model.n)} sampled"
            site = make_site(model, field, primitive, component, bits, precision)
            res = ray.get([a.contamination.remote(site, guard) for a in actors])
            stored = model.quantized(precision)
            box = support_box(stored, precision)
            row = stored.flat()[site.primitive].astype(np.float32)
            c = site.flat_component()
            bad = row.copy()
            bad[c] = encoding.from_bits(
                encoding.flip_bits(encoding.to_bits(row[c : c + 1], precision), list(site.bits), precision), precision
            )[0]
            clamped, _ = clamp_values(bad[None], box, component_mask(guarded_fields, model.sh_degree))
            out.update(
                {
                    "site": site,
                    "clean_value": float(row[c]),
                    "corrupted_value": float(bad[c]),
                    "guarded_value": float(clamped[0, c]),
                    "per_rank": res,
                    "reach_clean": footprint_reach(row, model.sh_degree, cameras, regions),
                    "reach_upset": footprint_reach(bad, model.sh_degree, cameras, regions),
                    "reach_guarded": footprint_reach(clamped[0], model.sh_degree, cameras, regions),
                    "touched_none": {r for r, x in enumerate(res) if x["none"]["changed"]},
                    "touched_guard": {r for r, x in enumerate(res) if x["guard"]["changed"]},
                }
            )
        return out
    finally:
        for a in actors:
            ray.kill(a)
        if started:
            ray.shutdown()


def _fmt_set(s) -> str:
    s = sorted(s)
    if not s:
        return "{}"
    return "{" + ", ".join(map(str, s)) + "}"


def print_sort_first(res: dict, console=None):
    """The per-rank table and the contamination summary (rich)."""
    from rich.console import Console
    from rich.table import Table

    if console is None:
        console = Console()
        if not console.is_terminal:
            console = Console(width=150)
    P, (px, py) = res["ranks"], res["grid"]
    t = Table(
        title=f"sort-first: {P} ranks ({px}x{py} grid) over {res['views']} view(s) of {res['width']}x"
        f"{res['height']}, {res['n']} primitives at {res['precision']}"
    )
    for col in ("rank", "region x,y,w,h", "render ms"):
        t.add_column(col, justify="right")
    up = "site" in res
    variant = res.get("guard_variant", "guard")
    if up:
        for col in ("reached", "changed px", f"changed px, {variant}", f"{variant} clamps", "reached, guarded"):
            t.add_column(col, justify="right")
    for r, vp in enumerate(res["regions"]):
        row = [str(r), ",".join(map(str, vp)), f"{1000 * res['times'][r]:.2f}" + (" *" if r == res["slowest"] else "")]
        if up:
            pr = res["per_rank"][r]
            row += [
                "yes" if r in res["reach_upset"] else "",
                str(pr["none"]["changed"]),
                str(pr["guard"]["changed"]),
                str(pr["guard"]["clamps"]),
                "yes" if r in res["reach_guarded"] else "",
            ]
        t.add_row(*row)
    console.print(t)
    times = res["times"]
    console.print(
        f"slowest rank: {res['slowest']} ({1000 * max(times):.2f} ms; mean {1000 * sum(times) / len(times):.2f} ms)"
        f"  load imbalance (max/mean): {res['imbalance']:.3f}  concurrent frame: "
        f"{1000 * res['frame_wall_s']:.1f} ms wall  (rank times measured one rank at a time)"
    )
    if up:
        s = res["site"]
        how = f" ({res['primitive_chosen']})" if "primitive_chosen" in res else ""
        console.print(
            f"upset: {s.field}[{s.primitive}][{s.component}] bit {','.join(map(str, s.bits))}{how}: "
            f"{res['clean_value']:.6g} -> {res['corrupted_value']:.6g}; {variant} reads {res['guarded_value']:.6g}"
        )
        console.print(f"  ranks its clean footprint reaches:     {_fmt_set(res['reach_clean'])}")
        console.print(f"  ranks its corrupted footprint reaches: {_fmt_set(res['reach_upset'])}")
        console.print(
            f"  ranks contaminated, no guard:          {_fmt_set(res['touched_none'])} "
            f"({len(res['touched_none'])} of {P})"
        )
        console.print(
            f"  ranks contaminated, node-local {variant}:  {_fmt_set(res['touched_guard'])} "
            f"({len(res['touched_guard'])} of {P}; its clamped footprint reaches {_fmt_set(res['reach_guarded'])})"
        )


def sort_first_tables(
    model, cameras, precision: str, ranks_list, upset=None, address: str | None = None, console=None, **kw
) -> list[dict]:
    """`seuwgpu distributed`: one Ray instance, one table per rank count. The worst primitive is
    chosen once (on the first rank count) so every table shows the same upset."""
    check_upset(model, upset, kw.get("primitive"), kw.get("component", 0), precision)
    started = init_ray(address)
    out = []
    try:
        chosen = None
        for p in ranks_list:
            res = sort_first(model, cameras, precision, p, upset, composite=False, **kw)
            if upset is not None and kw.get("primitive") is None:
                kw["primitive"], chosen = res["site"].primitive, res.get("primitive_chosen")
            elif chosen:
                res["primitive_chosen"] = chosen
            print_sort_first(res, console)
            out.append(res)
    finally:
        if started:
            get_ray().shutdown()
    return out
