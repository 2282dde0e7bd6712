"""Commands that read finished runs: `rates` and `report`."""

from __future__ import annotations

import argparse
from pathlib import Path

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import argument_type, float_word, positive_int
from seuwgpu.campaign.progress import ProgressBar
from seuwgpu.model import checks


def print_criticality(run_dirs):
    """run_dirs: run directories, or their store.campaign_runs."""
    from seuwgpu.analysis.records import InsufficientData
    from seuwgpu.report.build import criticality_table_text, load_runs, needs_folding

    df, _ = load_runs(run_dirs, fold=needs_folding(run_dirs))
    if df["profile"].nunique() > 1:  # as the report: the tables rest on the strict profile
        df = df[df["profile"] == "strict"]
    single = df[(df["k"] == 1) & (df["campaign"].isin(["single", "size"]))]
    for prec in sorted(single["precision"].unique()):
        try:
            table = criticality_table_text(single, prec)
        except InsufficientData as e:
            print(f"\n(no criticality table at {prec}: {e})")
            continue
        print(f"\nPer-field single-upset criticality at {prec} (defense: none)")
        print(table)


# ---- rates ------------------------------------------------------------------------------------------
def rates_arguments(s: argparse.ArgumentParser):
    s.add_argument("runs", type=Path, nargs="+")
    s.add_argument("--by", default="scene,precision,defense", help="comma-separated record columns (or run)")
    s.add_argument(
        "--campaign",
        default="single",
        choices=["single", "size"],
        help="records of the single-upset campaign (default) or of the primitive-count sweep",
    )
    s.add_argument("--csv", type=Path, help="write the table as CSV (rates as proportions)")


def cmd_rates(args):
    """Weighted outcome rates of runs (finished or still running), folded part by part."""
    from rich.console import Console
    from rich.table import Table

    from seuwgpu import api
    from seuwgpu.analysis.cells import COUNTS
    from seuwgpu.campaign.schema import check_record_columns

    by = list(dict.fromkeys(c.strip() for c in args.by.split(",") if c.strip()))  # a column named twice: once
    check_record_columns(by, "--by")
    with ProgressBar("reading parts") as bar:
        t = api.outcome_rates(args.runs, by=by, campaign=args.campaign, progress=bar.update)
    by, partial = t.attrs["groups"], t.attrs["partial"]
    if args.csv:
        from seuwgpu.campaign.store import make_out_dir

        make_out_dir(args.csv.parent, "--csv", "folder")
        t.to_csv(args.csv, index=False)
    tab = Table(
        title=f"{args.campaign} upsets, {t.attrs['records']:,} records in {t.attrs['parts']:,} parts: weighted "
        "rate per outcome, % [95% interval: Wilson per cell, stratified Wilson when pooled]"
    )
    for c in [*by, "n", *COUNTS]:
        tab.add_column(c, justify="right")
    for _, r in t.iterrows():
        pct = [[100 * r[f"{c}_{x}"] for x in ("rate", "ci_lo", "ci_hi")] for c in COUNTS]
        cells_text = (f"{p:.3g} [{lo:.3g}, {hi:.3g}]" for p, lo, hi in pct)
        tab.add_row(*(str(r[c]) for c in by), f"{int(r['n']):,}", *cells_text)
    Console(width=200).print(tab)
    if partial:
        print(partial)
    return 0


RATES = Command(
    "rates",
    "weighted outcome rates with intervals, read part by part (any size, runs still going)",
    rates_arguments,
    cmd_rates,
)


# ---- report -----------------------------------------------------------------------------------------
def report_arguments(s: argparse.ArgumentParser):
    s.add_argument("runs", type=Path, nargs="+")
    s.add_argument("--out", type=Path, required=True)
    s.add_argument(
        "--fold",
        choices=["auto", "yes", "no"],
        default="auto",
        help="fold the records as they are read (the same numbers in far less memory; auto: when "
        "they would not fit unfolded)",
    )
    s.add_argument(
        "--workers",
        type=positive_int,
        help="processes folding parts side by side (default: one per CPU, at most 8, from 256 parts on)",
    )
    s.add_argument(
        "--target",
        type=summary_target,
        help="residual catastrophic rate per upset the summary's cheapest defense must meet "
        "(default: the spec's [summary] target, else 0.001)",
    )


@argument_type
def summary_target(text: str) -> float:
    """A residual catastrophic rate per upset."""
    return checks.proportion(float_word(text), None, "0.001")


def cmd_report(args):

    from seuwgpu import api
    from seuwgpu.campaign.store import campaign_runs
    from seuwgpu.report.build import needs_folding

    runs = campaign_runs(args.runs)  # each manifest (and part footer) read once
    fold = {"auto": needs_folding(runs), "yes": True, "no": False}[args.fold]
    with ProgressBar("reading parts" + (" (folding)" if fold else "")) as bar:
        index = api.make_report(
            runs, args.out, fold=fold, progress=bar.update, workers=args.workers, target=args.target
        )
    print(f"wrote {index}")
    if fold:  # reading the records a second time would double a long load: the report's own table
        table = index.parent / "criticality.md"
        print(
            f"\nrecords folded as read (analysis/folding.py); per-field criticality at the reference "
            f"precision ({table}; every precision: {index.parent / 'field_bit.csv'}):"
        )
        if table.is_file():
            print(table.read_text())
    else:
        print_criticality(runs)
    return 0


REPORT = Command("report", "tables, figures and an HTML page from run directories", report_arguments, cmd_report)
