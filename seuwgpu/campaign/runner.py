"""Campaigns: many injections, batched, resumable, shardable, one Parquet row per (injection, defense).

The spec format is in `spec`, the enumeration and seeds in `sampling`, the run directory in
`store`. A Runner writes (a shard of) a campaign's blocks into a run directory, one atomic part per
block, skipping the parts already there; `replay` re-runs one injection alone from its id.
"""

from __future__ import annotations

import platform
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.campaign import schema, store
from seuwgpu.campaign.progress import injection_bar
from seuwgpu.campaign.sampling import Context, draw_sites, enumerate_contexts, injection_seeds
from seuwgpu.campaign.spec import SpecError
from seuwgpu.campaign.spec_hash import spec_hash
from seuwgpu.campaign.spec_types import Spec, as_spec
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.sites import draw_uniform_sites
from seuwgpu.metrics.image import FOOTPRINT_THRESHOLD, PIXEL_THRESHOLD, outcome_class
from seuwgpu.model import checks
from seuwgpu.render.regions import REGION_GRID_VERSION
from seuwgpu.version import __version__


class Runner:
    """Runs (a shard of) a campaign into a run directory (`out`; None: replay's, which writes
    nothing and keeps its view times in memory)."""

    def __init__(
        self,
        spec: Spec | dict,
        out: Path | None,
        shard: tuple[int, int] = (0, 1),
        quiet: bool = False,
        full: bool = False,
        gpu=None,
    ):
        spec = as_spec(spec)  # a Spec, or its stored form (a manifest's)
        self.spec, self.out = spec, None if out is None else Path(out)
        self.shard = checks.shard(shard)
        self.quiet, self.full = quiet, full
        self.gpu = gpu
        self.hash = spec_hash(spec)
        self.contexts = enumerate_contexts(spec)
        self.total = sum(c.count for c in self.contexts)
        t = spec.outcomes
        self.thresholds = {
            "pixel_threshold": float(PIXEL_THRESHOLD if t is None else t.pixel_threshold),
            "footprint_threshold": float(FOOTPRINT_THRESHOLD if t is None else t.footprint),
        }
        self._times: dict = {}  # engine key -> {defense: ms per view}
        # the last model file read (scene index, Source): a run's engines of one file (precisions,
        # [sizes]) and the new run's file check share one read; one slot, so memory stays bounded
        self._read: tuple[int, object] | None = None
        if spec.lpips:
            from seuwgpu.metrics.lpips import INSTALL_HINT, available

            if not available():
                raise SpecError(f"lpips = true: {INSTALL_HINT}")

    # -- run directory --
    def prepare_dir(self):
        rec = store.records_dir(self.out)
        rec.mkdir(parents=True, exist_ok=True)
        old = store.read_manifest(self.out)
        store.check_same_run(self.out, old, self.spec, self.hash)
        if old is None or old.get("spec_hash") != self.hash:
            from seuwgpu.faults.engine import Engine
            from seuwgpu.gpu.device import get_gpu

            models = self.check_files()
            gpu = self.gpu or get_gpu()
            manifest = {
                "spec": self.spec.to_dict(),
                "spec_hash": self.hash,
                "version": __version__,
                "git_commit": store.git_commit(),
                "adapter": {k: str(v) for k, v in gpu.info.items()},
                "python": platform.python_version(),
                "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
                "total_injections": self.total,
                "profile": self.spec.renderer_profile,
                "columns": schema.COLUMNS,
                "outcomes": self.thresholds,
                "region_grid": REGION_GRID_VERSION,
                "models": models,
                "time_ms": "median render time of one view (view 0, rendered alone) of the clean model under "
                "the defense's in-pipeline guard: the defenses timed interleaved just after the clean render "
                f"(no warm-up round), {Engine.VIEW_TIME_ROUNDS} rounds or as many (at least "
                f"{Engine.VIEW_TIME_LEAST_ROUNDS}) as fit {Engine.VIEW_TIME_BUDGET_S:g} s, once per engine and run "
                "(the rounds are in view_times/)",
            }
            if old is not None:
                store.forget_measurements(self.out)  # measured for the spec this one replaces
            store.write_manifest(self.out, manifest)
        store.remove_stale_temps(rec)

    def check_files(self) -> list[dict]:
        """Read each scene's model file once before a new run's manifest claims the directory: the
        spec check only hashes it, and a file that cannot be read would otherwise stop the run
        after the manifest was written, leaving a run folder with no records. (Camera files are
        read by the spec check already, so an embedded scene is not built here.) Returns what the
        manifest keeps of each scene's model (`models`): its label, format, primitives, SH degree and
        the loader's notes (what it changed: which LOD level was read, saturated opacities, an
        antialiased flag, ...), for the report's summary."""
        from seuwgpu.campaign.spec import scene_label
        from seuwgpu.model.captures import capture_antialiased
        from seuwgpu.model.formats import ANTIALIASED_NOTE
        from seuwgpu.model.scenes import is_capture
        from seuwgpu.model.sources import source_views

        models = []
        for i, sc in enumerate(self.spec.scenes):
            if sc.model is None:
                capture = is_capture(sc.scene)
                notes = [ANTIALIASED_NOTE] if capture and capture_antialiased(sc.scene) else []
                models.append(
                    {
                        "name": sc.scene,
                        "format": "embedded scene",
                        "primitives": sc.n,
                        "sh_degree": sc.sh_degree,
                        "notes": notes,
                    }
                )
                continue
            src = self.file_source(i)
            source_views(src, sc.cameras, self.spec.views, self.spec.size, self.spec.scale)
            models.append(
                {
                    "name": scene_label(sc),
                    "format": src.format,
                    "primitives": src.model.n,
                    "sh_degree": src.model.sh_degree,
                    "notes": list(src.notes),
                }
            )
        return models

    def file_source(self, scene_index: int):
        """Scene `scene_index`'s model file, loaded (or the last one loaded, when it is that)."""
        from seuwgpu.model.sources import load_source

        if self._read is None or self._read[0] != scene_index:
            self._read = None  # the previous model released before the next is read
            sc = self.spec.scenes[scene_index]
            self._read = (scene_index, load_source(path=sc.model, up=sc.up, lod=sc.lod))
        return self._read[1]

    def done_ids(self) -> set[tuple[int, int]]:
        """(first id, count) of this shard's parts already written and whole (a part that cannot be
        read, or holds the wrong number of rows, is deleted here and redone)."""
        want = store.expected_parts(self.spec)
        mine = {(a, m): want[(a, m)] for _, a, m in self.blocks()}
        return store.completed_parts(self.out, mine)

    def blocks(self):
        """Deterministic (context, first id, count) blocks of this shard."""
        i, n = self.shard
        bs = self.spec.batch
        j = 0
        for ctx in self.contexts:
            for a in range(0, ctx.count, bs):
                if j % n == i:
                    yield ctx, ctx.first_id + a, min(bs, ctx.count - a)
                j += 1

    def run(self, progress=None) -> dict:
        """Run the shard's blocks not yet recorded; returns {injections, new, catastrophic, seconds}.
        `progress(total, done)`: makes the progress object (advance(n, catastrophic), close()) once
        the run directory is locked and checked, with the shard's injections and those already
        recorded; default: a rich bar (or log lines when quiet)."""
        from seuwgpu.campaign.budget import check_campaign

        check_campaign(self.spec)
        with store.lock(self.out, self.shard):
            self.prepare_dir()
            return self._run(progress)

    def _run(self, progress) -> dict:
        done = self.done_ids()
        todo = [(c, a, m) for c, a, m in self.blocks() if (a, m) not in done]
        shard_total = sum(m for _, _, m in self.blocks())
        already = shard_total - sum(m for _, _, m in todo)
        stats = {"injections": already, "catastrophic": 0, "seconds": 0.0, "new": 0}
        bar = progress(shard_total, already) if progress else injection_bar(shard_total, already, self.quiet)
        engines, rates = {}, {}  # rates: sites a second of each engine's last group
        t0 = time.perf_counter()
        writer = store.PartWriter(self.out)
        finished = False
        try:
            i = 0
            while i < len(todo):
                t_group = time.perf_counter()
                ctx = todo[i][0]
                key = (ctx.kind, ctx.scene_index, ctx.n, ctx.precision)
                if key not in engines:
                    engines.clear()  # one engine at a time: bounded memory
                    engines[key] = self.engine_for(ctx)
                    self.note_clean_model(engines[key], ctx)
                eng = engines[key]
                group, i = self.next_group(todo, i, eng, rates.get(key))
                t_blocks = time.perf_counter()
                frames = self.run_blocks(eng, ctx, [(first, count) for _, first, count in group])
                seconds = time.perf_counter() - t_group
                total = sum(count for _, _, count in group)
                rates[key] = total / max(time.perf_counter() - t_blocks, 1e-9)
                for (_, first, count), df in zip(group, frames):
                    # a block's share of its group's time (recorded per part, summed by the reports)
                    writer.put(first, count, df, seconds=seconds * count / total)
                    cat = int(df.loc[df.defense == ctx.defenses[0], "catastrophic"].sum())
                    stats["injections"] += count
                    stats["new"] += count
                    stats["catastrophic"] += cat
                    bar.advance(count, cat)
            finished = True
        finally:
            bar.close()
            # the parts computed so far, written before an error or interrupt goes on; a write error
            # is raised on a normal exit only, never in place of the exception that ended the run
            writer.close(raise_error=finished)
        stats["seconds"] = time.perf_counter() - t0
        return stats

    # batches of the incremental evaluator evaluated per call: with two in flight (faults/incremental.py
    # lanes), the first and the last of a call run alone
    GROUP_BATCHES = 8
    # seconds a group may take at the rate measured so far: its parts are written when it ends, so
    # an interrupt loses at most this much work (and the progress bar moves at least this often)
    GROUP_SECONDS = 10.0

    def next_group(self, todo: list, i: int, eng, rate: float | None = None) -> tuple[list, int]:
        """(blocks todo[i:j] evaluated in one call, j): consecutive blocks of one single-upset context
        on the incremental path, up to GROUP_BATCHES evaluator batches of sites, so that a spec's
        small `batch` (the unit written and resumed) still fills a GPU's batches and pipeline, and
        no more sites than `rate` (sites a second so far) evaluates in GROUP_SECONDS. An
        interrupted run loses at most the group in progress."""
        ctx, group, sites = todo[i][0], [todo[i]], todo[i][2]
        i += 1
        if ctx.kind not in ("single", "size") or self.full or self.spec.lpips:
            return group, i
        target = self.GROUP_BATCHES * eng.evaluator.B
        if rate:
            target = min(target, max(eng.evaluator.B, int(rate * self.GROUP_SECONDS)))
        while i < len(todo) and todo[i][0] is ctx and sites + todo[i][2] <= target:
            group.append(todo[i])
            sites += todo[i][2]
            i += 1
        return group, i

    def note_clean_model(self, eng, ctx: Context):
        """A clean model holding NaN/Inf: the guard's own effect on it (per guard arm), written
        once beside the manifest instead of being charged to every upset."""
        if not eng.nonfinite_counts:
            return
        note = {d: eng.guard_on_clean(d) for d in dfn.pipeline_guards() if d in ctx.defenses}
        note["nonfinite_values"] = dict(eng.nonfinite_counts)
        store.write_guard_note(self.out, eng.scene, ctx.precision, eng.profile, note)

    def engine_for(self, ctx: Context):
        """The engine of `ctx`'s model, views and precision. While the model is read or made, a
        thread compiles the pipelines of an engine of its shape (Engine.warm_up)."""
        from seuwgpu.faults.engine import Engine
        from seuwgpu.gpu.device import get_gpu
        from seuwgpu.model.sources import load_source, source_views

        gpu = self.gpu or get_gpu()
        sc = self.spec.scenes[ctx.scene_index]
        stand_in = self.stand_in_views(sc)
        with ThreadPoolExecutor(1) as pool:
            warm = None
            if stand_in:
                # a model file's degree is known once read (a new run's file check reads it first)
                read = self._read and self._read[0] == ctx.scene_index and self._read[1].model
                degree = read.sh_degree if sc.model and read else sc.sh_degree
                profile = self.spec.renderer_profile
                warm = pool.submit(Engine.warm_up, stand_in, ctx.precision, profile, not self.full, gpu, degree)
            if sc.model:
                src = self.file_source(ctx.scene_index)
            else:
                src = load_source(scene=sc.scene, n=ctx.n or sc.n, sh_degree=sc.sh_degree, seed=sc.seed, up=sc.up)
            views = source_views(src, sc.cameras, self.spec.views, self.spec.size, self.spec.scale)
            model = src.model
            if sc.model and ctx.n is not None:  # a model file in the primitive-count sweep: framed whole, then cut
                model = model.sample(ctx.n, sc.seed, src.name)
            if warm is not None:
                warm.result()
        return Engine(
            model,
            views,
            ctx.precision,
            gpu=gpu,
            scene=src.name,
            incremental=not self.full,
            profile=self.spec.renderer_profile,
        )

    def stand_in_views(self, sc) -> list | None:
        """Orbit views of a stand-in scene with the number and size of `sc`'s views (for
        Engine.warm_up); None where a camera file gives them (it is read with the model)."""
        from seuwgpu.model.sources import Source, source_views

        if sc.cameras is not None or self.spec.size is None:
            return None
        stand_in = Source(None, "warm-up", "+z", "spheres")
        return source_views(stand_in, None, self.spec.views, self.spec.size, self.spec.scale)

    def view_times(self, eng, ctx: Context) -> dict:
        """ms per view of each defense's render of the clean model: measured once per engine and
        run (kept in the run directory, store.claim_view_times), so a resumed run does not pay the
        measurement again and every part of the run records the same time_ms."""
        key = (id(eng), ctx.kind, ctx.scene_index, ctx.n, ctx.precision, tuple(ctx.defenses))
        if key not in self._times:
            name = f"{ctx.kind}-scene{ctx.scene_index}-n{ctx.n or eng.n}-{ctx.precision}"
            stored = store.read_view_times(self.out, name) if self.out is not None else None
            if stored is None or not set(ctx.defenses) <= set(stored.get("time_ms", {})):
                samples = eng.view_time_samples(ctx.defenses)
                stored = {
                    "time_ms": {d: float(np.median(v)) for d, v in samples.items()},
                    "samples_ms": samples,
                    "views": "view 0 alone" if not eng.renderer.batched else f"all {eng.k} views, over {eng.k}",
                    "adapter": str(eng.gpu.info.get("device", "?")),
                    "measured": time.strftime("%Y-%m-%dT%H:%M:%S"),
                }
                if self.out is not None:
                    stored = store.claim_view_times(self.out, name, stored)
            self._times[key] = {d: float(stored["time_ms"][d]) for d in ctx.defenses}
        return self._times[key]

    def lpips_of(self, eng, sites, defense: str) -> float:
        """LPIPS of the frame with `sites` flipped under `defense` against clean (a full render;
        NaN for a frame with a non-finite pixel)."""
        from seuwgpu.metrics.lpips import lpips

        handle = eng.apply(sites, defense)
        try:
            img, _ = eng.render_current(defense)
        finally:
            eng.undo(handle)
        return float(np.mean(lpips(eng.clean_rgba[..., :3], img[..., :3])))  # NaN if any view is

    def finish(self, df: pd.DataFrame, eng, ctx: Context) -> pd.DataFrame:
        """Outcome class and catastrophic flag under the spec's thresholds; time_ms per defense."""
        t = self.thresholds
        df["outcome"] = outcome_class(
            df["peak_error"].to_numpy(float),
            df["footprint"].to_numpy(float),
            df["nonfinite"].to_numpy(bool),
            t["pixel_threshold"],
            t["footprint_threshold"],
        )
        df["catastrophic"] = df["outcome"].to_numpy() == "catastrophic"
        df["time_ms"] = df["defense"].map(self.view_times(eng, ctx)).astype(float)
        return df.reindex(columns=schema.columns_of(ctx))

    def run_block(self, eng, ctx: Context, first: int, count: int) -> pd.DataFrame:
        return self.run_blocks(eng, ctx, [(first, count)])[0]

    def run_blocks(self, eng, ctx: Context, blocks: list) -> list[pd.DataFrame]:
        """The records of each (first id, count) block of `ctx`; single-upset blocks are evaluated in
        one call (each variant's numbers do not depend on its batch: tests/test_campaign.py)."""
        if ctx.kind not in ("single", "size"):
            return [self._dose_block(eng, ctx, first, count) for first, count in blocks]
        ids = np.concatenate([np.arange(first, first + count, dtype=np.int64) for first, count in blocks])
        seeds = injection_seeds(self.spec.seed, ids)
        every, weights = draw_sites(ctx, ids - ctx.first_id, seeds, eng.n, eng.degree)  # per injection
        if self.full:
            if ctx.regions:
                raise SpecError("regions (sort-first contamination) are measured on the incremental path; drop --full")
            whole = pd.DataFrame([eng.inject(s, d) for d in ctx.defenses for s in every])
        else:
            whole = eng.evaluate_frame(every, ctx.defenses, ctx.regions)
        arms = len(ctx.defenses)  # rows are defense-major: arm d holds rows d*total .. d*total+total-1
        if self.spec.lpips:
            whole["lpips"] = [self.lpips_of(eng, [s], d) for d in ctx.defenses for s in every]
        whole["campaign"] = ctx.kind
        whole["repeat"] = 0
        whole["weight"] = np.tile(weights, arms)
        whole["seed"] = np.tile(seeds, arms)
        whole["injection_id"] = np.tile(ids, arms)
        whole = self.finish(whole, eng, ctx)  # once per group: the columns are row by row
        ends = np.cumsum([count for _, count in blocks])
        arm_rows = np.arange(arms)[:, None] * len(ids)
        return [
            whole.iloc[(arm_rows + np.arange(end - count, end)[None, :]).ravel()].reset_index(drop=True)
            for (_, count), end in zip(blocks, ends)
        ]

    def _dose_block(self, eng, ctx: Context, first: int, count: int) -> pd.DataFrame:
        ids = np.arange(first, first + count, dtype=np.int64)
        seeds = injection_seeds(self.spec.seed, ids)
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
                if self.spec.lpips:
                    rec["lpips"] = self.lpips_of(eng, sites, d)
                rows.append(rec)
        return self.finish(pd.DataFrame(rows), eng, ctx)


def replay(spec: Spec | dict, injection_id: int, full: bool = False, gpu=None) -> pd.DataFrame:
    """Re-run one injection alone from its id: its rows (one per defense), as the campaign wrote them."""
    runner = Runner(spec, None, full=full, gpu=gpu)
    for ctx in runner.contexts:
        if ctx.first_id <= injection_id < ctx.first_id + ctx.count:
            eng = runner.engine_for(ctx)
            return runner.run_block(eng, ctx, injection_id, 1)
    raise ValueError(f"injection id {injection_id} is not in this campaign (0..{runner.total - 1})")
