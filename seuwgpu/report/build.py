"""Turn campaign runs into a report a reviewer can read: HTML page, PNG figures, CSV/MD tables.

    df, manifests = load_runs(["runs/a", "runs/b"])
    index = build_report(["runs/a", "runs/b"], "report/")      # -> report/index.html
    print(criticality_table_text(df))                          # the CLI's per-field table

The analyses are `seuwgpu.analysis`'s; `report.sections` turns each into a section (tables, figures,
notes, headline numbers) and `report.format` writes values and tables. `build_report` writes into
out_dir (flat):
  index.html      self-contained page (figures embedded as base64 PNG), opening with the summary
                  (report/summary.py: the model, p_c, the most dangerous cells, the worst flip's
                  panel, each defense's cost, the cheapest meeting a target), one section per analysis,
                  each table and figure captioned with the runs, scenes, precisions and record
                  counts it rests on, and a "Skipped analyses" section saying what is missing
                  and which campaign would supply it;
  fig_*.png       every figure, also beside the page;
  <table>.csv / <table>.md   every table (CSV with full precision, Markdown with a caption);
  report.md       the whole report as Markdown (tables inline, figures linked);
  summary.json    headline numbers, provenance of the runs and the skipped list.
"""

from __future__ import annotations

import base64
import contextlib
import datetime as _dt
import html
import io
import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.analysis import (
    criticality,
    folding,
    outcomes,
)
from seuwgpu.analysis.contamination import region_sum_columns
from seuwgpu.analysis.records import (
    FIELD_LABELS,
    MULTIPLICITY,
    PREDICTION_SAMPLE,
    prediction_draw,
    prepare,
    provenance,
    provenance_text,
    thresholds_of,
)
from seuwgpu.campaign import store
from seuwgpu.report.format import html_table, json_default, json_safe, markdown_table
from seuwgpu.report.sections import (
    SECTIONS,
    FigureItem,
    Section,
    TableItem,
    profile_section,
    run_sections,
    section_figures,
)
from seuwgpu.version import __version__

__all__ = [
    "load_runs",
    "build_report",
    "criticality_table_text",
    "markdown_table",
    "Section",
    "TableItem",
    "FigureItem",
    "SECTIONS",
    "run_sections",
    "section_figures",
]

OPTIONAL_COLUMNS = ("campaign", "repeat", "time_ms")


# ------------------------------------------------------------------------------------ loading


# Peak host memory per record while a report is built, unfolded and folded as read
# (analysis/folding.py), from the measurements in docs/benchmarks.md ("Report memory"); scenes
# whose records fold less need more.
REPORT_BYTES_PER_RECORD = 2000
FOLDED_BYTES_PER_RECORD = 139


def check_report_memory(run_dirs, folded: bool = False) -> int:
    """Refuse, before loading anything, runs whose report would not fit in host memory (their
    record count from the Parquet footers; folded: as analysis/folding.py reads them); returns
    that count. The rates of any number of records are `seuwgpu rates`'s (analysis/cells.py).
    run_dirs: run directories, or their store.campaign_runs (footers read once, kept there)."""
    from seuwgpu.errors import TooBig
    from seuwgpu.model.budget import HOST_SHARE, available_host_bytes, available_text, gb

    n = 0
    for run in store.campaign_runs(run_dirs):
        if run.path.is_dir():
            n += sum(rows or 0 for rows in run.rows().values())
    need = n * (FOLDED_BYTES_PER_RECORD if folded else REPORT_BYTES_PER_RECORD)
    have = HOST_SHARE * available_host_bytes()
    if need > have:
        how = "even folded as read" if folded else "unfolded (`--fold yes` needs about 14x less)"
        raise TooBig(
            f"a report of {n:,} records needs about {gb(need)} of host memory {how}, {available_text(have)}: "
            "report fewer runs, or read the weighted outcome rates of any number of records "
            "with `seuwgpu rates RUN...`"
        )
    return n


FOLD_CHUNK = 256  # folded parts joined into one frame while reading


def needs_folding(run_dirs) -> bool:
    """Whether the runs' records fit in host memory only folded (check_report_memory)."""
    from seuwgpu.errors import TooBig

    try:
        check_report_memory(run_dirs)
    except TooBig:
        return True
    return False


def load_runs(
    run_dirs: Iterable[str | Path],
    *,
    fold: bool = False,
    max_pred_rows: int = 200_000,
    progress=None,
    workers: int | None = None,
) -> tuple[pd.DataFrame, list[dict]]:
    """Concatenate the records of campaign run directories.

    Each run directory holds manifest.json and records/part-*.parquet. Returns the records (with
    a ``run`` column naming the run directory, optional columns filled by
    `analysis.prepare`) and the manifests (each with ``_run`` and ``_run_dir`` added).
    A missing manifest is tolerated (an empty one is used); a run without parquet parts is an
    error. fold=True folds the records part by part as they are read (analysis.folding; every
    number of the report unchanged, memory bounded by the distinct rows), keeping a random
    sample of about max_pred_rows records per precision for the prediction. `progress(i, n)` is
    called per part read. workers: processes folding parts side by side (fold_workers; the
    frame is the same, part for part in the same order, whatever their number). run_dirs may be
    store.campaign_runs of the folders (each manifest then read once for a whole report)."""
    if isinstance(run_dirs, (str, Path)):
        run_dirs = [run_dirs]
    info = store.campaign_runs(run_dirs)
    store.refuse_repeated_sites(info, "report one of them")
    check_report_memory(info, folded=fold)
    runs, manifests = [], []
    for run in info:
        p = run.path
        if not p.is_dir():
            raise FileNotFoundError(f"{p}: not a run directory")
        manifest = dict(run.manifest)
        parts = run.parts  # the spec's parts only: a stray file is never counted
        manifest["_run"] = run.name
        manifest["_run_dir"] = str(p)
        if not parts:
            visible = any(store.visible_path(p, "*").parent.glob("*.parquet"))
            hint = (
                " (it holds visible-damage records alone, `defenses --visible N --out`, which a campaign's "
                "report shows beside its records: run a campaign into it, `seuwgpu campaign SPEC --out`)"
                if visible
                else ""
            )
            raise FileNotFoundError(f"{p}: no records/part-*.parquet{hint}")
        runs.append((run.name, parts))
        manifests.append(manifest)
    thresholds = thresholds_of(manifests)
    total = sum(len(parts) for _, parts in runs) * (2 if fold else 1)  # folding reads twice
    workers = fold_workers(total // 2, workers) if fold else 1
    with _part_mapper(workers) as map_parts:
        shares = _prediction_shares(runs, max_pred_rows, progress, total, map_parts) if fold else {}
        # several profiles: the report rests on the strict records but for the others' rates
        profiles = {p for p, _ in shares}
        rates_only = profiles - {"strict"} if "strict" in profiles else set()
        frames, pending, n_all = [], [], 0
        done = total // 2 if fold else 0
        for (name, parts), manifest in zip(runs, manifests):
            n, sites = 0, []
            if fold:
                jobs = [(part, name, thresholds, shares, rates_only) for part in parts]
                read = map_parts(_fold_part_file, jobs)
            else:
                read = ((f, None, len(f)) for f in (_read_part(part, name) for part in parts))
            for f, hashes, records in read:
                done += 1
                if progress:
                    progress(done, total)
                if not records:
                    continue
                n += records
                if fold:
                    sites.append(hashes)
                pending.append(f)
                if fold and len(pending) >= FOLD_CHUNK:  # a few big frames, not thousands of small ones
                    frames.append(pd.concat(pending, ignore_index=True, sort=False))
                    pending = []
            if fold and sites:
                h = np.concatenate(sites)
                if len(np.unique(h)) < len(h):
                    raise ValueError(
                        f"{name}: fault sites whose defenses lie in different parts (records written by "
                        "another tool?); folding pairs defenses within a part: report these runs unfolded"
                    )
            manifest["_n_records"] = n
            n_all += n
    frames += pending
    if not frames:
        raise ValueError("the runs hold no records")
    df = pd.concat(frames, ignore_index=True, sort=False)
    del frames, pending
    # an unfinished run: every table made of these records says so (criticality_table_text)
    partial = store.partial_runs_text(info)
    if not fold:
        df = prepare(df, thresholds)
        df.attrs["partial"] = partial
        return df, manifests
    import pyarrow as pa

    pa.default_memory_pool().release_unused()  # the parts' buffers, freed but kept by the pool
    df[MULTIPLICITY] = df[MULTIPLICITY].astype(np.int64)
    df[PREDICTION_SAMPLE] = df[PREDICTION_SAMPLE].astype(bool)
    sums = region_sum_columns(df.columns)
    df[sums] = df[sums].fillna(0.0)  # parts without the columns: nothing measured there
    df.attrs.update(
        _seuwgpu_prepared=True,
        thresholds=dict(thresholds),
        folded={"records": n_all, "rows": len(df)},
        partial=partial,
    )
    return df, manifests


def _parquet(part: Path, columns=None) -> pd.DataFrame:
    from seuwgpu.campaign.store import read_part
    from seuwgpu.errors import InputError

    try:
        return read_part(part, columns)  # its column types checked against the records' schema
    except InputError:
        raise
    except (OSError, ValueError) as e:  # pyarrow's ArrowInvalid is a ValueError
        raise InputError(f"{part}: not a readable record part ({e})") from None


def _read_part(part: Path, run: str) -> pd.DataFrame:
    f = _parquet(part)
    f["run"] = run
    for c in f.columns:
        # region bitmasks: keep them exact integers when other parts lack the column
        # (a plain int64 column would widen to float64 and lose bits above 2^53)
        if str(c).startswith("regions_") and pd.api.types.is_integer_dtype(f[c]):
            v = f[c].to_numpy()
            if v.dtype == np.uint64:
                v = v.view(np.int64)
            f[c] = pd.array(v, dtype="Int64")
    return f


def _prediction_shares(runs, max_pred_rows: int, progress=None, total: int = 0, map_parts=map) -> dict:
    """Per (profile, precision): the probability with which folding keeps a record for the
    prediction's sample, from a first pass over a few columns of every part."""
    counts: dict = {}
    done = 0
    for _, parts in runs:
        for population in map_parts(_prediction_population_of, parts):
            done += 1
            if progress:
                progress(done, total)
            for key, n in population.items():
                counts[key] = counts.get(key, 0) + int(n)
    return {key: prediction_draw(n, max_pred_rows) for key, n in counts.items()}


def _prediction_population_of(part: Path) -> dict:
    import pyarrow.parquet as pq

    cols = ["campaign", "k", "defense", "bit", "precision", "profile"]
    try:
        have = set(pq.read_schema(part).names)
    except (OSError, ValueError):
        have = set(cols)  # unreadable: _parquet says so, naming the file
    f = prepare(_parquet(part, [c for c in cols if c in have]))  # its defaults for absent columns
    return dict(folding.prediction_population(f))


def _fold_part_file(job) -> tuple[pd.DataFrame | None, np.ndarray | None, int]:
    """One part read, prepared and folded (a worker's task): (folded rows, the hashes of its
    fault sites, its record count); (None, None, 0) for an empty part."""
    part, name, thresholds, shares, rates_only = job
    f = _read_part(part, name)
    if len(f) == 0:
        return None, None, 0
    if "weight" not in f or f["weight"].isna().any():
        raise ValueError(f"{part}: records without weights (an older version) cannot be folded: report fewer runs")
    n = len(f)
    f = prepare(f, thresholds)
    hashes = folding.site_hashes(f)
    return folding.fold_part(f, shares, rates_only), hashes, n


# Parts below which folding stays in this process: starting a worker (a fresh interpreter that
# imports pandas and this package) costs about as much as folding a hundred parts.
PARALLEL_MIN_PARTS = 256


def fold_workers(n_parts: int, workers: int | None = None) -> int:
    """Processes that fold parts: `workers` when given, else one per CPU (at most 8) for runs of at
    least PARALLEL_MIN_PARTS parts, else 1 (this process)."""
    import os

    if workers is not None:
        if int(workers) < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        return int(workers)
    if n_parts < PARALLEL_MIN_PARTS:
        return 1
    return max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


@contextlib.contextmanager
def _part_mapper(workers: int):
    """`map` over parts, in order: this process's own for one worker, else a pool of fresh
    processes (spawned, not forked: a caller such as tools/study.py holds a GPU device whose
    threads a fork would copy mid-flight). On an error the parts not yet folded are dropped."""
    if workers <= 1:
        yield map
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        yield lambda fn, items: pool.map(fn, items, chunksize=8)
    finally:
        pool.shutdown(cancel_futures=True)


# ----------------------------------------------------------------------------- build report


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
h3{font-size:1.05em;margin-bottom:.3em}
table{border-collapse:collapse;font-size:.82em;margin:.4em 0 1em 0;display:block;overflow-x:auto}
th,td{border:1px solid #ddd;padding:.2em .5em}th{background:#f3f3f3}td.txt{max-width:18em;white-space:normal;
overflow-wrap:anywhere}td.num{text-align:right;
font-variant-numeric:tabular-nums}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}
.cap{font-size:.86em;color:#444}.note{font-size:.88em;color:#555}
.skip{background:#fff8e6;border-left:4px solid #f0b429;padding:.5em 1em}
.warn{background:#fdecea;border-left:4px solid #d93025;padding:.5em 1em}
code{background:#f5f5f5;padding:0 .2em}
"""


def build_report(
    run_dirs: Iterable[str | Path],
    out_dir: str | Path,
    *,
    title: str = "seuwgpu: single-event upsets in 3D Gaussian splatting",
    max_pred_rows: int = 200_000,
    fold: bool | None = None,
    progress=None,
    workers: int | None = None,
    target: float | None = None,
    panel: bool = True,
) -> Path:
    """Write the report of the given runs into out_dir; returns the path of index.html.
    target: the residual catastrophic rate per upset the summary's cheapest defense must meet
    (None: the specs' `[summary] target`, else analysis.summary.DEFAULT_TARGET); panel: render the
    worst flip's panel again (report/summary.py; False: its `seuwgpu inject` command line only).
    fold: fold the records as they are read (load_runs); None folds only runs whose records would
    not fit in host memory unfolded (check_report_memory); workers: processes folding the parts
    (load_runs)."""
    if isinstance(run_dirs, (str, Path)):
        run_dirs = [run_dirs]
    runs = store.campaign_runs(run_dirs)  # each manifest read, and each footer, once for the report
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if fold is None:
        fold = needs_folding(runs)
    df, manifests = load_runs(runs, fold=fold, max_pred_rows=max_pred_rows, progress=progress, workers=workers)
    partial = df.attrs.get("partial", "")  # store.partial_runs_text of the runs, made by load_runs
    previous = _previous_files(out)
    written: list[str] = []
    ctx = {"skipped": [], "max_pred_rows": max_pred_rows, "results": {}}
    by_profile = profile_section(df)
    if by_profile is not None:  # never pool renderer profiles: the analyses rest on strict records
        df = df[df["profile"] == "strict"].copy()
    sections = run_sections(df, manifests, ctx)
    if by_profile is not None:
        sections.append(by_profile)
    skipped = ctx["skipped"]
    # the summary opens the report (the user's question answered), then the paper's claims, with
    # the rows these records measure (report/summary.py)
    from seuwgpu.report.summary import summary_section, trim_claims

    for sec in sections:
        if sec.key == "claims":
            trim_claims(sec)
    sections.insert(0, summary_section(df, manifests, target, panel))
    sections.sort(key=lambda sec: {"summary": 0, "claims": 1}.get(sec.key, 2))

    # files
    md_parts = [f"# {title}\n", f"\n**{partial}**\n" if partial else ""]
    html_sections = []
    toc = []
    numbers: dict = {}
    for sec in sections:
        numbers.update(sec.numbers)
        toc.append(f"<li><a href='#{sec.key}'>{html.escape(sec.title)}</a></li>")
        hs = [f"<h2 id='{sec.key}'>{html.escape(sec.title)}</h2>"]
        md_parts.append(f"\n## {sec.title}\n\n{sec.text}\n")
        if sec.text:
            hs.append(f"<p>{html.escape(sec.text)}</p>")
        for fi in sec.figures:
            png = _png(fi.fig)
            (out / f"{fi.name}.png").write_bytes(png)
            written.append(f"{fi.name}.png")
            b64 = base64.b64encode(png).decode("ascii")
            cap = fi.full_caption()
            hs.append(
                f"<figure><img alt='{html.escape(fi.title)}' "
                f"src='data:image/png;base64,{b64}'><figcaption class='cap'><b>"
                f"{html.escape(fi.title)}.</b> {html.escape(cap)} "
                f"(<a href='{fi.name}.png'>{fi.name}.png</a>)</figcaption></figure>"
            )
            md_parts.append(f"\n![{fi.title}]({fi.name}.png)\n\n*{fi.title}.* {cap}\n")
        for ti in sec.tables:
            cap = ti.full_caption()
            ti.df.to_csv(out / f"{ti.name}.csv", index=False)
            mdt = markdown_table(ti.df)
            (out / f"{ti.name}.md").write_text(
                f"**{ti.title}.** {cap}\n\n{mdt}" + (f"\n**{partial}**\n" if partial else "")
            )
            written += [f"{ti.name}.csv", f"{ti.name}.md"]
            links = f"(<a href='{ti.name}.csv'>{ti.name}.csv</a>, <a href='{ti.name}.md'>{ti.name}.md</a>)"
            body = (
                f"<p class='note'>{len(ti.df):,} rows: linked, not inlined.</p>" if ti.csv_only else html_table(ti.df)
            )
            hs.append(f"<h3>{html.escape(ti.title)}</h3><p class='cap'>{html.escape(cap)} {links}</p>{body}")
            if ti.csv_only:
                md_parts.append(f"\n**{ti.title}.** {cap} ({len(ti.df):,} rows: [{ti.name}.csv]({ti.name}.csv))\n")
            else:
                md_parts.append(f"\n**{ti.title}.** {cap}\n\n{mdt}")
        if sec.notes:
            hs.append("<ul class='note'>" + "".join(f"<li>{html.escape(n)}</li>" for n in sec.notes) + "</ul>")
            md_parts.append("\n" + "".join(f"- {n}\n" for n in sec.notes))
        html_sections.append("\n".join(hs))
        if sec.key == "summary":  # the runs' table after the summary, which opens the report
            md_parts.append("\n## Runs\n" + _runs_markdown(df, manifests))

    skip_rows = pd.DataFrame(skipped, columns=["analysis", "missing", "what would supply it"])
    toc.append("<li><a href='#skipped'>Skipped analyses</a></li>")
    if len(skip_rows):
        skip_html = (
            "<div class='skip'><p>These analyses were skipped, for lack of data or of an optional library:</p>"
            + html_table(skip_rows)
            + "</div>"
        )
    else:
        skip_html = "<p>None: every analysis had the data it needs.</p>"
    skip_rows.to_csv(out / "skipped.csv", index=False)
    (out / "skipped.md").write_text(
        "**Skipped analyses.**\n\n" + (markdown_table(skip_rows) if len(skip_rows) else "None.\n")
    )
    md_parts.append("\n## Skipped analyses\n\n" + (markdown_table(skip_rows) if len(skip_rows) else "None.\n"))
    (out / "report.md").write_text("".join(md_parts))

    summary = {
        "title": title,
        "partial": partial or None,
        "generated": _dt.datetime.now(_dt.UTC).isoformat(),
        "seuwgpu_version": __version__,
        "provenance": provenance(df),
        "runs": [_run_info(m) for m in manifests],
        "sections": [s.key for s in sections],
        "skipped": [{"analysis": a, "missing": b, "remedy": c} for a, b, c in skipped],
        "thresholds": dict(df.attrs.get("thresholds", {})),
        "folded": df.attrs.get("folded"),
        "catastrophic": outcomes.catastrophic_summary(df),
        "numbers": numbers,
        "files": sorted(written + ["index.html", "report.md", "summary.json", "skipped.csv", "skipped.md"]),
    }
    # files an earlier report wrote here that this one does not (an analysis now skipped):
    # remove them so the folder never shows stale results; nothing else is touched
    for name in previous - set(summary["files"]):
        try:
            (out / name).unlink()
        except OSError:
            pass
    (out / "summary.json").write_text(json.dumps(json_safe(summary), indent=2, default=json_default, allow_nan=False))

    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>{_CSS}</style></head><body>
<h1>{html.escape(title)}</h1>
<p class='note'>Generated {html.escape(summary["generated"])} by seuwgpu {html.escape(__version__)}.
{html.escape(provenance_text(provenance(df)))} {html.escape(_folded_text(df))}</p>
{f"<p class='warn'><b>{html.escape(partial)}</b></p>" if partial else ""}
{html_sections[0]}
<h2>Runs</h2>{html_table(_runs_table(manifests))}
<h2>Contents</h2><ul>{"".join(toc)}</ul>
{"".join(html_sections[1:])}
<h2 id='skipped'>Skipped analyses</h2>{skip_html}
<h2>Conventions</h2><ul class='note'>
<li>Proportions carry 95% intervals (never a normal approximation).</li>
<li>Footprint: % of pixels changed by more than 1/255 in any channel, mean over views;
catastrophic: footprint &gt; 1% or any non-finite pixel.</li>
<li>Every rate, mean and quantile is weighted by the stored bits each record stands for
(a uniform upset's view; stratified (field, bit) cells are not pooled unweighted); intervals are
Wilson per cell and, pooled, stratified Wilson at the design-effect effective sample size
(stratum variances from add-half rates).</li>
<li>PSNR and SSIM of a frame with a non-finite pixel are undefined (NaN in the records); summaries
are over the finite frames, with the share of non-finite frames beside them.</li>
<li>Reference precision for single-precision tables: fp32 when present.</li>
</ul>
</body></html>
"""
    index = out / "index.html"
    index.write_text(page)
    return index


def _previous_files(out: Path) -> set[str]:
    """Files listed by an earlier report's summary.json in out (plain names only)."""
    try:
        files = json.loads((out / "summary.json").read_text()).get("files", [])
    except (OSError, ValueError, AttributeError):
        return set()
    return {f for f in files if isinstance(f, str) and f == Path(f).name and f}


def _run_info(m: dict) -> dict:
    adapter = m.get("adapter") or {}
    if isinstance(adapter, dict):
        adapter = adapter.get("device") or adapter.get("name") or adapter.get("description") or json.dumps(adapter)[:80]
    return {
        "run": m.get("_run"),
        "dir": m.get("_run_dir"),
        "records": m.get("_n_records"),
        "spec_hash": m.get("spec_hash"),
        "version": m.get("version"),
        "git_commit": m.get("git_commit"),
        "adapter": str(adapter) if adapter else None,
    }


def _runs_table(manifests: list[dict]) -> pd.DataFrame:
    return pd.DataFrame([_run_info(m) for m in manifests])


def _folded_text(df) -> str:
    f = df.attrs.get("folded")
    if not f:
        return ""
    return (
        f"The {f['records']:,} records were folded as they were read into {f['rows']:,} rows of alike "
        "records (analysis/folding.py): every number is that of the records themselves."
    )


def _runs_markdown(df, manifests) -> str:
    folded = _folded_text(df)
    return (
        "\n"
        + provenance_text(provenance(df))
        + (f" {folded}" if folded else "")
        + "\n\n"
        + (markdown_table(_runs_table(manifests)))
    )


# ------------------------------------------------------------------------------ CLI helper


def criticality_table_text(df: pd.DataFrame, precision: str | None = None) -> str:
    """The per-field criticality table as Markdown (what `seuwgpu report` prints)."""
    crit = criticality.criticality(df, precision)
    prec = crit.attrs["precision"]
    rows = []
    for _, r in crit.iterrows():
        rows.append(
            {
                "Field": FIELD_LABELS.get(r["field"], r["field"]),
                "n": int(r["n"]),
                "median": f"{r['median_pct']:.3f}",
                "p95": f"{r['p95_pct']:.3f}",
                "p99": f"{r['p99_pct']:.3g}",
                "max": f"{r['max_pct']:.3g}",
                "mean": f"{r['mean_pct']:.3f}",
                "catastrophe (%, 95% CI)": f"{r['cat_rate_pct']:.3f} "
                f"[{r['cat_ci_lo_pct']:.3f}, {r['cat_ci_hi_pct']:.3f}]",
            }
        )
    t = pd.DataFrame(rows)
    head = (
        f"Per-field single-bit upset severity at {prec} (no defense), pooled over scenes and "
        "bits; weighted footprint quantiles in % of frame; catastrophe rate with its 95% interval.\n"
        f"{provenance_text(crit.attrs.get('provenance', {}))}\n\n"
    )
    partial = df.attrs.get("partial")  # load_runs: an unfinished run's table says so
    foot = f"\n{partial}\n" if partial else ""
    lines = ["| " + " | ".join(t.columns) + " |", "|---|" + "|".join("---:" for _ in t.columns[1:]) + "|"]
    for row in t.itertuples(index=False):
        lines.append("| " + " | ".join(str(x) for x in row) + " |")
    return head + "\n".join(lines) + "\n" + foot
