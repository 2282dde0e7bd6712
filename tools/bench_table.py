"""The tables tools/bench.py prints from its JSON document."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_stages import STAGES  # noqa: E402


def _fmt(x, spec=".1f"):
    return "-" if x is None else format(x, spec)


def _config_label(r: dict) -> str:
    """A record's compositor shape, and ", 1 by 1" where its K > 1 views were not batched."""
    return r.get("compositor", "lanes") + ("" if r.get("batched", True) or r["k"] == 1 else ", 1 by 1")


def print_table(doc: dict, console=None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = console or Console(width=200)
    a = doc["adapter"]
    stages_known = any(r.get("stages_ms") for r in doc["results"])
    title = f"seuwgpu render benchmark - {a['device']} ({a['backend']}, {a['adapter_type']}; {a['description']})"
    table = Table(title=title, title_justify="left")
    for col in ("scene", "N", "size", "K", "compositor", "R", "Mpix/s", "ms/view", "min ms/view"):
        table.add_column(col, justify="right" if col not in ("scene", "compositor") else "left")
    if stages_known:
        for s in (*STAGES, "gaps"):
            table.add_column(s, justify="right")
    table.add_column("twin s/view", justify="right")
    table.add_column("GPU/twin speed", justify="right")
    table.add_column("PSNR v0", justify="right")
    for r in doc["results"]:
        row = [
            r["scene"],
            f"{r['n']:,}",
            f"{r['width']}x{r['height']}",
            str(r["k"]),
            _config_label(r),
            str(r["repeats"]),
            f"{r['mpix_per_s']:.3f}",
            f"{r['ms_per_view']:.1f}",
            f"{r['min_ms_per_view']:.1f}",
        ]
        if stages_known:
            st = r.get("stages_ms") or {}
            row += [_fmt(st.get(s)) for s in (*STAGES, "gaps")]
        tw = r.get("twin")
        if tw is None:
            row += ["-", "-"]
        elif r.get("twin_ratio") is None:
            row += [f"{tw['seconds_per_view']:.2f} @N={tw['n']:,}", "n/a (other N)"]
        else:
            row += [f"{tw['seconds_per_view']:.2f}", f"{r['twin_ratio']:.1f}x"]
        row.append(_fmt(r.get("psnr_view0_vs_twin_db")))
        table.add_row(*row)
    console.print(table)
    notes = []
    if stages_known:
        notes.append(
            "Stage columns: GPU ms per submission (summed over the K views) from timestamp queries on one "
            "separate instrumented submission, one column per render stage (render/pipeline.py; 'emit' includes the "
            "tile counts and their prefix sum); 'gaps' = time "
            "between passes. Mpix/s and ms/view come from un-instrumented submissions."
        )
    else:
        notes.append("No per-stage times: " + (doc["results"][0]["stage_source"] if doc["results"] else "no results"))
    notes.append(
        "Mpix/s = K*W*H / median wall time of R submissions (encode + submit + wait), warm-up excluded; "
        "ms/view = median / K; min ms/view = fastest of the R / K (other load on the host slows runs)."
    )
    notes.append(
        "twin s/view: numpy reference.render measured in this run on orbit view 0 (K=1) at the same N and "
        "size; GPU/twin speed = twin s/view / GPU s/view of the row. PSNR v0: GPU view 0 vs the twin's."
    )
    h = doc["host"]
    notes.append(
        f"Host: {h['cpus']} CPUs, load average {h['loadavg_start'][0]:.1f} at start, "
        f"{h['loadavg_end'][0]:.1f} at end; total wall time {doc['total_wall_s']:.0f} s."
    )
    for n in notes:
        console.print(n)
    fl = doc.get("floors")
    if fl and any(r.get("floors_ms_per_view") for r in doc["results"]):
        ft = Table(
            title=f"stages against measured floors (per view): exp {fl['exp_per_s'] / 1e6:,.0f} M/s, "
            f"copy {fl['copy_bytes_per_s'] / 1e9:.2f} GB/s",
            title_justify="left",
        )
        for col in ("scene", "N", "size", "K", "compositor", *STAGES):
            ft.add_column(col, justify="left" if col in ("scene", "compositor") else "right")
        for r in doc["results"]:
            fms, st = r.get("floors_ms_per_view"), r.get("stages_ms")
            if not fms or not st:
                continue
            cells = []
            for s in STAGES:
                t = st[s] / r["k"]
                f = fms.get(s)
                cells.append(f"{t:.1f} ms" if f is None else f"{t:.1f} / {f:.1f} ms ({100 * f / max(t, 1e-9):.0f}%)")
            ft.add_row(
                r["scene"],
                f"{r['n']:,}",
                f"{r['width']}x{r['height']}",
                str(r["k"]),
                _config_label(r),
                *cells,
            )
        console.print(ft)
        console.print(
            "Cells: stage time / floor (ms per view) and % of floor (floor / time). Compositing's floor evaluates "
            "every listed pair at every pixel of its tile at the exp-loop rate; the others move their bytes at the "
            "copy rate (tools/bench.py STAGE_BYTES)."
        )
    for c in doc.get("chunking", []):
        console.print(
            f"Long tile lists ({c['scene']}, N={c['n']:,} shrunk x{c['dense_factor']}, {c['width']}x{c['height']}, "
            f"K={c['k']}; {c['long_tiles']} of {c['tiles']} tiles over {c['chunk']} pairs, up to "
            f"{c['max_pairs_per_tile']:,}): {c['ms_per_view_chunked']:.1f} ms/view in chunks, "
            f"{c['ms_per_view_off']:.1f} ms/view with chunking off ({c['speedup']:.2f}x; PSNR between them "
            f"{c['psnr_view0_chunked_vs_off_db']:.1f} dB)"
        )
    for shape, err in doc.get("compositor_errors", {}).items():
        console.print(f"Compositor {shape} failed on this device and was dropped from the run: {err.splitlines()[0]}")
    for c in doc.get("campaigns", []):
        console.print(
            f"Campaign ({c['scene']}, N={c['n']:,}, K={c['views']} at {c['size']}x{c['size']}, incremental path): "
            f"{c['injections_per_s']:,.1f} injections/s ({c['injections']} injections in {c['seconds']:.2f} s)"
        )
