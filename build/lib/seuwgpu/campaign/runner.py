"""Campaigns: many injections, batched, resumable, shardable, one Parquet row per (injection, defense).

Spec (TOML; unknown keys and bad values fail at once, naming the key):

    seed = 0                 # master seed
    views = 4                # orbit views per scene (K)
    size = "128x128"         # WxH
    batch = 256              # injections per GPU batch and per Parquet part

    [[scenes]]               # one or more
    scene = "spheres"        # an embedded scene ... or: ply = "model.ply"
    n = 100000               # primitives of an embedded scene
    sh_degree = 3
    cameras = "CAMS.json"    # optional, instead of orbit views

    [single]                 # single upsets, stratified by (field, bit) cell
    precisions = ["fp32"]
    fields = "all"           # or a list of field names
    bits = "all"             # or a list of bit indices (those valid for each precision)
    samples = 20             # injections per (field, bit) cell, or a plan:
                             # samples = {margin = 0.02, confidence = 0.95} (Leveugle et al. 2009,
                             # worst case p = 0.5, finite population of the smallest cell)
    sampling = "stratified"  # or "uniform": `samples` x cells injections drawn uniformly over
                             # all stored bits (weight column = bits each sample stands for)
    defenses = ["none", "guard"]
    regions = [4, 16, 64]    # optional: sort-first contamination columns regions_pred_P and
                             # regions_meas_P (int64 bitmasks of the P regions reached/changed)

    [dose]                   # k simultaneous upsets drawn uniformly over the whole bit budget
    precisions = ["fp32"]
    k = [1, 10, 100]         # or k_max = 20000 and points = 12 (log-spaced, rounded, distinct)
    repeats = 3
    defenses = ["none", "guard"]

    [sizes]                  # primitive-count sweep of the first scene: single upsets at each N
    n = [5000, 20000, 80000]
    precisions = ["fp32"]
    fields = "all"
    bits = "all"
    samples = 10
    defenses = ["none"]

Every injection has an id (its index in the deterministic enumeration) and a seed derived from the
master seed and that id alone, so any injection can be replayed by itself, and batching, order or
sharding never change a record. All defense arms of an injection see the same site (paired).
Records are written in atomic parts (temp file + rename); re-running the same command skips the
parts already written, and a changed spec is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.faults.sites import Site, draw_uniform_sites, site_from_flat
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS, canonical_field, field_components
from seuwgpu.version import __version__

# ---- spec --------------------------------------------------------------------------------------
_TOP = {"seed", "views", "size", "batch", "scenes", "single", "dose", "sizes", "name"}
_SCENE = {"scene", "ply", "n", "sh_degree", "cameras", "seed"}
_SINGLE = {"precisions", "fields", "bits", "samples", "sampling", "defenses", "regions"}
_DOSE = {"precisions", "k", "k_max", "points", "repeats", "defenses"}
_SIZES = {"n", "precisions", "fields", "bits", "samples", "defenses", "sampling", "regions"}


class SpecError(ValueError):
    pass


def _keys(table: dict, allowed: set, where: str):
    if not isinstance(table, dict):
        raise SpecError(f"{where} must be a table")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SpecError(
            f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(repr(k) for k in unknown)} in {where} "
            f"(allowed: {', '.join(sorted(allowed))})"
        )


def _int(table, key, where, default=None, lo=None, hi=None):
    v = table.get(key, default)
    if v is None:
        raise SpecError(f"{where}.{key} is required")
    if isinstance(v, bool) or not isinstance(v, int):
        raise SpecError(f"{where}.{key} must be an integer, got {v!r}")
    if lo is not None and v < lo or hi is not None and v > hi:
        raise SpecError(f"{where}.{key} = {v} is out of range [{lo}, {hi if hi is not None else 'inf'}]")
    return v


def _list(table, key, where, default, valid=None):
    v = table.get(key, default)
    if isinstance(v, str) and v == "all" and valid is not None:
        return list(valid)
    if not isinstance(v, list) or not v:
        raise SpecError(f"{where}.{key} must be a non-empty list" + (' or "all"' if valid is not None else ""))
    if valid is not None:
        bad = [x for x in v if x not in valid]
        if bad:
            raise SpecError(f"{where}.{key}: unknown value(s) {bad}; valid: {list(valid)}")
    return v


def _fields(table, where):
    v = table.get("fields", "all")
    if v == "all":
        return list(FIELDS)
    if not isinstance(v, list) or not v:
        raise SpecError(f'{where}.fields must be "all" or a list of fields')
    try:
        return [canonical_field(f) for f in v]
    except ValueError as e:
        raise SpecError(f"{where}.fields: {e}") from None


def _bits(table, where, precisions):
    v = table.get("bits", "all")
    if v == "all":
        return "all"
    if not isinstance(v, list) or not v or not all(isinstance(b, int) and not isinstance(b, bool) for b in v):
        raise SpecError(f'{where}.bits must be "all" or a list of bit indices')
    for p in precisions:
        for b in v:
            if not 0 <= b < encoding.bits_per_value(p):
                raise SpecError(f"{where}.bits: bit {b} is out of range for {p} (0..{encoding.bits_per_value(p) - 1})")
    return sorted(set(v))


def _samples(table, where, default, n_min: int | None):
    """`samples` as an int, or planned from {margin, confidence} (stats.sample_size)."""
    v = table.get("samples", default)
    if isinstance(v, dict):
        _keys(v, {"margin", "confidence"}, f"{where}.samples")
        from seuwgpu.campaign.plan import sample_size

        margin, conf = v.get("margin"), v.get("confidence", 0.95)
        if not isinstance(margin, (int, float)) or not 0 < margin < 1:
            raise SpecError(f"{where}.samples.margin must be a proportion in (0, 1), e.g. 0.02")
        if not isinstance(conf, (int, float)) or not 0 < conf < 1:
            raise SpecError(f"{where}.samples.confidence must be in (0, 1), e.g. 0.95")
        # the smallest cell is one field's values at one bit: n_primitives x 1 component at least
        return int(sample_size(float(margin), float(conf), population=n_min))
    return _int(table, "samples", where, default, 1)


def _spec_file(table, key, where, base_dir: Path | None) -> str:
    """A file named in the spec, relative to the spec's folder; it must exist."""
    path = Path(table[key])
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    if not path.exists():
        raise SpecError(f"{where}.{key}: file not found: {path}")
    return str(path)


def _regions(table, where, size):
    """Sort-first partition sizes P for contamination columns (regions_pred_P, regions_meas_P)."""
    v = table.get("regions", [])
    if not isinstance(v, list) or not all(isinstance(p, int) and not isinstance(p, bool) for p in v):
        raise SpecError(f"{where}.regions must be a list of partition sizes, e.g. [4, 16, 64]")
    for p in v:
        if not 2 <= p <= 64:
            raise SpecError(f"{where}.regions: P = {p} is out of range [2, 64] (regions are 64-bit masks)")
        if p > size[0] * size[1]:
            raise SpecError(f"{where}.regions: P = {p} is more regions than pixels")
    return sorted(set(v))


def parse_size(v, where="size"):
    if isinstance(v, str):
        try:
            w, h = (int(x) for x in v.lower().split("x"))
        except ValueError:
            raise SpecError(f'{where} must look like "128x128", got {v!r}') from None
    elif isinstance(v, list) and len(v) == 2:
        w, h = v
    else:
        raise SpecError(f'{where} must look like "128x128", got {v!r}')
    if not (isinstance(w, int) and isinstance(h, int)) or w < 16 or h < 16:
        raise SpecError(f"{where}: width and height must be integers >= 16, got {v!r}")
    return int(w), int(h)


def dose_levels(k_max: int, points: int) -> list[int]:
    ks = np.unique(np.round(np.logspace(0, np.log10(k_max), points)).astype(int))
    return [int(k) for k in ks]


def normalize_spec(raw: dict, base_dir: Path | None = None) -> dict:
    """Validated spec with defaults filled in (what is hashed and stored in the manifest)."""
    from seuwgpu.model.scenes import list_scenes

    _keys(raw, _TOP, "the spec")
    spec = {
        "name": str(raw.get("name", "campaign")),
        "seed": _int(raw, "seed", "spec", 0, 0),
        "views": _int(raw, "views", "spec", 4, 1, 64),
        "size": list(parse_size(raw.get("size", "128x128"))),
        "batch": _int(raw, "batch", "spec", 256, 1, 65536),
    }
    scenes = raw.get("scenes")
    if not isinstance(scenes, list) or not scenes:
        raise SpecError("the spec needs at least one [[scenes]] table")
    spec["scenes"] = []
    for i, s in enumerate(scenes):
        where = f"scenes[{i}]"
        _keys(s, _SCENE, where)
        if ("scene" in s) == ("ply" in s):
            raise SpecError(f"{where} needs exactly one of scene = NAME or ply = FILE")
        out = {"sh_degree": _int(s, "sh_degree", where, 3, 0, 3), "seed": _int(s, "seed", where, 0, 0)}
        if "scene" in s:
            if s["scene"] not in list_scenes():
                raise SpecError(
                    f"{where}.scene: unknown scene {s['scene']!r}; embedded scenes: {', '.join(list_scenes())}"
                )
            out["scene"] = s["scene"]
            out["n"] = _int(s, "n", where, 100_000, 1)
        else:
            out["ply"] = _spec_file(s, "ply", where, base_dir)
        if "cameras" in s:
            out["cameras"] = _spec_file(s, "cameras", where, base_dir)
        spec["scenes"].append(out)
    if not any(k in raw for k in ("single", "dose", "sizes")):
        raise SpecError("the spec needs at least one of [single], [dose], [sizes]")
    if "single" in raw:
        t = raw["single"]
        _keys(t, _SINGLE, "single")
        precisions = _list(t, "precisions", "single", ["fp32"], encoding.PRECISIONS)
        spec["single"] = {
            "precisions": precisions,
            "fields": _fields(t, "single"),
            "bits": _bits(t, "single", precisions),
            "samples": _samples(t, "single", 20, min((sc.get("n") or 10**9) for sc in spec["scenes"])),
            "sampling": t.get("sampling", "stratified"),
            "defenses": _list(t, "defenses", "single", ["none", "guard"], DEFENSES),
            "regions": _regions(t, "single", spec["size"]),
        }
        if spec["single"]["sampling"] not in ("stratified", "uniform"):
            raise SpecError(f'single.sampling must be "stratified" or "uniform", got {t["sampling"]!r}')
    if "dose" in raw:
        t = raw["dose"]
        _keys(t, _DOSE, "dose")
        if "k" in t and ("k_max" in t or "points" in t):
            raise SpecError("dose: give either k = [...] or k_max and points, not both")
        if "k" in t:
            ks = _list(t, "k", "dose", None)
            if not all(isinstance(k, int) and not isinstance(k, bool) and 1 <= k for k in ks):
                raise SpecError("dose.k must be a list of positive integers")
        else:
            ks = dose_levels(_int(t, "k_max", "dose", 20_000, 1), _int(t, "points", "dose", 12, 1, 200))
        spec["dose"] = {
            "precisions": _list(t, "precisions", "dose", ["fp32"], encoding.PRECISIONS),
            "k": sorted(set(int(k) for k in ks)),
            "repeats": _int(t, "repeats", "dose", 3, 1),
            "defenses": _list(t, "defenses", "dose", ["none", "guard"], DEFENSES),
        }
    if "sizes" in raw:
        t = raw["sizes"]
        _keys(t, _SIZES, "sizes")
        if "scene" not in spec["scenes"][0]:
            raise SpecError("sizes: the first [[scenes]] entry must be an embedded scene (it is generated at each n)")
        ns = _list(t, "n", "sizes", None)
        if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in ns):
            raise SpecError("sizes.n must be a list of positive integers")
        precisions = _list(t, "precisions", "sizes", ["fp32"], encoding.PRECISIONS)
        spec["sizes"] = {
            "n": sorted(set(ns)),
            "precisions": precisions,
            "fields": _fields(t, "sizes"),
            "bits": _bits(t, "sizes", precisions),
            "samples": _samples(t, "sizes", 10, min(ns)),
            "sampling": t.get("sampling", "stratified"),
            "defenses": _list(t, "defenses", "sizes", ["none"], DEFENSES),
            "regions": _regions(t, "sizes", spec["size"]),
        }
    return spec


def load_spec(path) -> dict:
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: not valid TOML ({e})") from None
    except FileNotFoundError:
        raise SpecError(f"{path}: file not found") from None
    return normalize_spec(raw, path.parent)


def spec_hash(spec: dict) -> str:
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


# ---- enumeration -------------------------------------------------------------------------------
@dataclass
class Context:
    """One engine set-up: a scene at a primitive count and precision, and its injections."""

    kind: str  # "single" | "dose" | "size"
    scene_index: int
    n: int | None  # primitive count (None: as loaded)
    precision: str
    defenses: list
    first_id: int
    count: int
    cells: list = dc_field(default_factory=list)  # single/size: [(field, bit)]; dose: [k]
    per_cell: int = 0  # samples (single/size) or repeats (dose)
    sampling: str = "stratified"
    regions: tuple = ()  # sort-first partition sizes measured for single upsets

    def cell_of(self, local: int):
        return self.cells[local // self.per_cell], local % self.per_cell


def _cells(fields, bits, precision):
    nb = encoding.bits_per_value(precision)
    use = range(nb) if bits == "all" else [b for b in bits if b < nb]
    return [(f, b) for f in fields for b in use]


def enumerate_contexts(spec: dict) -> list[Context]:
    ctxs, nid = [], 0
    if "single" in spec:
        t = spec["single"]
        for si, sc in enumerate(spec["scenes"]):
            for p in t["precisions"]:
                cells = _cells(t["fields"], t["bits"], p)
                c = Context(
                    "single",
                    si,
                    sc.get("n"),
                    p,
                    t["defenses"],
                    nid,
                    len(cells) * t["samples"],
                    cells,
                    t["samples"],
                    t["sampling"],
                    tuple(t.get("regions", ())),
                )
                ctxs.append(c)
                nid += c.count
    if "dose" in spec:
        t = spec["dose"]
        for si, sc in enumerate(spec["scenes"]):
            for p in t["precisions"]:
                c = Context(
                    "dose",
                    si,
                    sc.get("n"),
                    p,
                    t["defenses"],
                    nid,
                    len(t["k"]) * t["repeats"],
                    list(t["k"]),
                    t["repeats"],
                )
                ctxs.append(c)
                nid += c.count
    if "sizes" in spec:
        t = spec["sizes"]
        for n in t["n"]:
            for p in t["precisions"]:
                cells = _cells(t["fields"], t["bits"], p)
                c = Context(
                    "size",
                    0,
                    n,
                    p,
                    t["defenses"],
                    nid,
                    len(cells) * t["samples"],
                    cells,
                    t["samples"],
                    t["sampling"],
                    tuple(t.get("regions", ())),
                )
                ctxs.append(c)
                nid += c.count
    return ctxs


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays (wrapping arithmetic): a counter-based hash, so any
    injection's random numbers follow from (master seed, id) alone, vectorised over a block."""
    x = np.asarray(x, dtype=np.uint64) + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def injection_seeds(master: int, ids) -> np.ndarray:
    """Per-injection 63-bit seeds (the records' `seed` column) of a block of injection ids."""
    key = _splitmix64(np.array([master], dtype=np.uint64))[0]
    return (_splitmix64(np.asarray(ids, dtype=np.uint64) ^ key) >> np.uint64(1)).astype(np.int64)


def injection_seed(master: int, injection_id: int) -> int:
    return int(injection_seeds(master, [injection_id])[0])


def _stream(seeds: np.ndarray, k: int) -> np.ndarray:
    """The k-th 64-bit random number of each injection's stream."""
    return _splitmix64(seeds.astype(np.uint64) * np.uint64(0x100000001B3) + np.uint64(k))


def draw_sites(ctx: Context, local: np.ndarray, seeds: np.ndarray, n: int, degree: int):
    """Sites of a block of single-upset injections and their weights (stored bits each stands
    for). Stratified: cell local // samples, primitive and component uniform within it; uniform:
    one stored bit uniform over the whole budget. Returns (sites, weights)."""
    nb = encoding.bits_per_value(ctx.precision)
    local = np.asarray(local, dtype=np.int64)
    if ctx.sampling == "uniform":
        ncomp = 14 + 3 * ((degree + 1) ** 2 - 1)
        total = n * ncomp * nb
        flat = (_stream(seeds, 0) % np.uint64(total)).astype(np.int64)
        prim, rest = np.divmod(flat, ncomp * nb)
        comp, bit = np.divmod(rest, nb)
        sites = [site_from_flat(int(p), int(c), (int(b),), degree) for p, c, b in zip(prim, comp, bit)]
        return sites, np.full(local.size, total / (len(ctx.cells) * ctx.per_cell))
    cell = local // ctx.per_cell
    prim = (_stream(seeds, 1) % np.uint64(n)).astype(np.int64)
    r2 = _stream(seeds, 2)
    sites, weights = [], np.empty(local.size)
    for j, c in enumerate(cell):
        field, bit = ctx.cells[c]
        nc = field_components(field, degree)
        sites.append(Site(field, int(prim[j]), int(r2[j] % np.uint64(nc)), (int(bit),)))
        weights[j] = n * nc / ctx.per_cell
    return sites, weights


# ---- running -----------------------------------------------------------------------------------
COLUMNS = [
    "campaign",
    "scene",
    "n_primitives",
    "precision",
    "field",
    "primitive",
    "component",
    "bit",
    "bit_class",
    "clean_value",
    "corrupted_value",
    "defense",
    "footprint",
    "footprint_max",
    "peak_error",
    "psnr",
    "ssim",
    "nonfinite",
    "catastrophic",
    "clamps",
    "k",
    "repeat",
    "weight",
    "seed",
    "injection_id",
]


def columns_of(ctx: Context) -> list[str]:
    return COLUMNS + [f"regions_{kind}_{P}" for P in ctx.regions for kind in ("pred", "meas")]


def _git_commit() -> str:
    try:
        return (
            subprocess.run(
                ["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True, text=True, timeout=5
            ).stdout.strip()
            or "unknown"
        )
    except Exception:
        return "unknown"


class Runner:
    """Runs (a shard of) a campaign into a run directory."""

    def __init__(
        self, spec: dict, out: Path, shard: tuple[int, int] = (0, 1), quiet: bool = False, full: bool = False, gpu=None
    ):
        self.spec, self.out = spec, Path(out)
        self.shard = shard
        self.quiet, self.full = quiet, full
        self.gpu = gpu
        self.hash = spec_hash(spec)
        self.contexts = enumerate_contexts(spec)
        self.total = sum(c.count for c in self.contexts)

    # -- run directory --
    def prepare_dir(self):
        rec = self.out / "records"
        rec.mkdir(parents=True, exist_ok=True)
        mpath = self.out / "manifest.json"
        if mpath.exists():
            old = json.loads(mpath.read_text())
            if old.get("spec_hash") != self.hash:
                raise SpecError(
                    f"{self.out} holds a run of a different spec (hash {old.get('spec_hash')} != {self.hash}); "
                    "use a new --out directory, or the original spec to resume"
                )
        else:
            from seuwgpu.gpu.device import get_gpu

            gpu = self.gpu or get_gpu()
            manifest = {
                "spec": self.spec,
                "spec_hash": self.hash,
                "version": __version__,
                "git_commit": _git_commit(),
                "adapter": {k: str(v) for k, v in gpu.info.items()},
                "python": platform.python_version(),
                "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
                "total_injections": self.total,
                "columns": COLUMNS,
            }
            atomic_write(mpath, json.dumps(manifest, indent=1).encode())
        _remove_stale_temps(rec)

    def done_ids(self) -> set[tuple[int, int]]:
        """(first id, count) of the parts already written."""
        done = set()
        for p in (self.out / "records").glob("part-*.parquet"):
            a, b = p.stem.split("-")[1:3]
            done.add((int(a), int(b)))
        return done

    def blocks(self):
        """Deterministic (context, first id, count) blocks of this shard."""
        i, n = self.shard
        bs = self.spec["batch"]
        j = 0
        for ctx in self.contexts:
            for a in range(0, ctx.count, bs):
                if j % n == i:
                    yield ctx, ctx.first_id + a, min(bs, ctx.count - a)
                j += 1

    def run(self, progress=None) -> dict:
        self.prepare_dir()
        done = self.done_ids()
        todo = [(c, a, m) for c, a, m in self.blocks() if (a, m) not in done]
        shard_total = sum(m for _, _, m in self.blocks())
        already = shard_total - sum(m for _, _, m in todo)
        stats = {"injections": already, "catastrophic": 0, "seconds": 0.0, "new": 0}
        bar = progress or Progress(shard_total, already, self.quiet)
        engines = {}
        t0 = time.perf_counter()
        try:
            for ctx, first, count in todo:
                key = (ctx.kind, ctx.scene_index, ctx.n, ctx.precision)
                if key not in engines:
                    engines.clear()  # one engine at a time: bounded memory
                    engines[key] = self.engine_for(ctx)
                eng = engines[key]
                df = self.run_block(eng, ctx, first, count)
                atomic_write(self.out / "records" / f"part-{first:010d}-{count:06d}.parquet", _parquet_bytes(df))
                cat = int(df.loc[df.defense == ctx.defenses[0], "catastrophic"].sum())
                stats["injections"] += count
                stats["new"] += count
                stats["catastrophic"] += cat
                bar.advance(count, cat)
        finally:
            bar.close()
        stats["seconds"] = time.perf_counter() - t0
        return stats

    def engine_for(self, ctx: Context):
        from seuwgpu.faults.engine import Engine
        from seuwgpu.model.cameras import load_cameras
        from seuwgpu.model.ply import load_ply
        from seuwgpu.model.scenes import make_scene, scene_cameras

        sc = self.spec["scenes"][ctx.scene_index]
        w, h = self.spec["size"]
        if "scene" in sc:
            model = make_scene(sc["scene"], n=ctx.n or sc["n"], sh_degree=sc["sh_degree"], seed=sc["seed"])
            name = sc["scene"]
            cams = load_cameras(sc["cameras"]) if "cameras" in sc else scene_cameras(name, self.spec["views"], w, h)
        else:
            model = load_ply(sc["ply"])
            name = Path(sc["ply"]).stem
            from seuwgpu.model.cameras import orbit_cameras

            cams = load_cameras(sc["cameras"]) if "cameras" in sc else orbit_cameras(self.spec["views"], w, h)
        return Engine(model, cams, ctx.precision, gpu=self.gpu, scene=name, incremental=not self.full)

    def run_block(self, eng, ctx: Context, first: int, count: int) -> pd.DataFrame:
        ids = np.arange(first, first + count, dtype=np.int64)
        seeds = injection_seeds(self.spec["seed"], ids)
        if ctx.kind in ("single", "size"):
            sites, weights = draw_sites(ctx, ids - ctx.first_id, seeds, eng.n, eng.degree)
            if self.full:
                if ctx.regions:
                    raise SpecError(
                        "regions (sort-first contamination) are measured on the incremental path; drop --full"
                    )
                df = pd.DataFrame([eng.inject(s, d) for d in ctx.defenses for s in sites])
            else:
                df = eng.evaluate_frame(sites, ctx.defenses, ctx.regions)
            arms = len(ctx.defenses)  # rows are defense-major: arm d holds rows d*count .. d*count+count-1
            df["campaign"] = ctx.kind
            df["repeat"] = 0
            df["weight"] = np.tile(weights, arms)
            df["seed"] = np.tile(seeds, arms)
            df["injection_id"] = np.tile(ids, arms)
            return df.reindex(columns=columns_of(ctx))
        rows = []
        for i, s in zip(ids, seeds):
            k, rep = ctx.cell_of(int(i) - ctx.first_id)
            try:
                sites = draw_uniform_sites(eng.n, eng.degree, eng.precision, k, np.random.default_rng(int(s)))
            except ValueError as e:
                raise SpecError(f"dose: {e}") from None
            for d in ctx.defenses:
                rec = eng.inject(sites, d)
                rec.update(campaign="dose", repeat=rep, weight=1.0, seed=int(s), injection_id=int(i))
                rows.append(rec)
        return pd.DataFrame(rows).reindex(columns=columns_of(ctx))


def _parquet_bytes(df: pd.DataFrame) -> bytes:
    import io

    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


def _host() -> str:
    return platform.node().replace(".", "_") or "host"


def _remove_stale_temps(folder: Path):
    """Delete half-written parts left by dead writers of this host (other shards may share the
    folder: their live temp files, and other hosts', are left alone)."""
    host = _host()
    for tmp in folder.glob("*.tmp"):
        parts = tmp.name.rsplit(".", 3)  # NAME.parquet . host . pid . tmp
        if len(parts) != 4 or parts[1] != host:
            continue
        try:
            os.kill(int(parts[2]), 0)
        except (ProcessLookupError, ValueError):
            tmp.unlink(missing_ok=True)
        except PermissionError:
            pass


def atomic_write(path: Path, data: bytes):
    tmp = path.with_name(path.name + f".{_host()}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read_records(run_dir) -> pd.DataFrame:
    parts = sorted((Path(run_dir) / "records").glob("part-*.parquet"))
    if not parts:
        return pd.DataFrame(columns=COLUMNS)
    return pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)


def merge(out: Path, shard_dirs: list[Path]) -> int:
    """Join shard run directories (same spec) into one; refuses mixed specs and duplicates."""
    import shutil

    out = Path(out)
    manifests = [json.loads((Path(d) / "manifest.json").read_text()) for d in shard_dirs]
    hashes = {m["spec_hash"] for m in manifests}
    if len(hashes) != 1:
        raise SpecError(f"shards come from different specs: {sorted(hashes)}")
    (out / "records").mkdir(parents=True, exist_ok=True)
    seen = {}
    for d in shard_dirs:
        for p in sorted((Path(d) / "records").glob("part-*.parquet")):
            if p.name in seen:
                if p.read_bytes() != seen[p.name].read_bytes():
                    raise SpecError(f"part {p.name} differs between {seen[p.name].parent.parent} and {d}")
                continue
            seen[p.name] = p
            shutil.copyfile(p, out / "records" / p.name)
    m = dict(manifests[0])
    m["merged_from"] = [str(d) for d in shard_dirs]
    atomic_write(out / "manifest.json", json.dumps(m, indent=1).encode())
    return len(seen)


class Progress:
    """rich progress with injections/s, ETA and the running catastrophe count; quiet mode logs lines."""

    def __init__(self, total: int, done: int, quiet: bool):
        self.total, self.done, self.quiet = total, done, quiet
        self.cat = 0
        self.t0 = time.perf_counter()
        self.last = self.t0
        self.start_done = done
        if not quiet:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.p = Progress(
                TextColumn("[bold]injections"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[rate]:>8.1f}/s"),
                TimeElapsedColumn(),
                TextColumn("ETA"),
                TimeRemainingColumn(),
                TextColumn("catastrophic: {task.fields[cat]}"),
                transient=False,
            )
            self.p.start()
            self.task = self.p.add_task("run", total=total, completed=done, rate=0.0, cat=0)

    def advance(self, n: int, cat: int):
        self.done += n
        self.cat += cat
        now = time.perf_counter()
        rate = (self.done - self.start_done) / max(now - self.t0, 1e-9)
        if not self.quiet:
            self.p.update(self.task, completed=self.done, rate=rate, cat=self.cat)
        elif now - self.last > 10 or self.done == self.total:
            self.last = now
            print(
                f"{self.done}/{self.total} injections, {rate:.1f}/s, catastrophic {self.cat}",
                file=sys.stderr,
                flush=True,
            )

    def close(self):
        if not self.quiet:
            self.p.stop()


def replay(spec: dict, injection_id: int, full: bool = False, gpu=None) -> pd.DataFrame:
    """Re-run one injection alone from its id: its rows (one per defense), as the campaign wrote them."""
    runner = Runner(spec, Path("."), full=full, gpu=gpu)
    for ctx in runner.contexts:
        if ctx.first_id <= injection_id < ctx.first_id + ctx.count:
            eng = runner.engine_for(ctx)
            return runner.run_block(eng, ctx, injection_id, 1)
    raise ValueError(f"injection id {injection_id} is not in this campaign (0..{runner.total - 1})")
