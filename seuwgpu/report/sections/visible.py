"""What the user sees, in the defenses section: the visible-damage records a run folder keeps
(`seuwgpu defenses --visible N --out RUN`; analysis/visible.py). No records, no table."""

from __future__ import annotations

from seuwgpu.analysis.visible import visible_table
from seuwgpu.campaign.visible import read_counts
from seuwgpu.report.sections.base import TableItem

COLUMNS = {
    "scene": "scene",
    "precision": "precision",
    "width": "width",
    "height": "height",
    "fault": "fault",
    "upsets": "upsets",
    "window": "window",
    "defense": "defense",
    "check_every": "S",
    "catastrophic_frames_per_upset": "catastrophic frames / upset",
    "catastrophic_lo": "catastrophic lo",
    "catastrophic_hi": "catastrophic hi",
    "residue_frames_per_upset": "after the check",  # the post-check residue, beside what is seen
    "sdc_frames_per_upset": "SDC frames / upset",
    "sdc_lo": "SDC lo",
    "sdc_hi": "SDC hi",
    "of_none": "x none",
    "of_none_lo": "x none lo",
    "of_none_hi": "x none hi",
    "device": "device",
    "date": "date",
}


def visible_item(manifests) -> tuple[TableItem, dict] | None:
    """(the table of what the user sees per defense and schedule, its headline numbers), or None
    when the runs' folders hold no visible-damage records."""
    counts = read_counts([m["_run_dir"] for m in manifests if m.get("_run_dir")])
    if counts is None:
        return None
    t = visible_table(counts)
    numbers = {
        f"visible_catastrophic_{r['scene']}_{r['defense']}_S{r['schedule']}_w{r['window']}": r[
            "catastrophic_frames_per_upset"
        ]
        for r in t.to_dict("records")
    }
    cap = (
        "What the user sees (campaign/visible.py, measured by `seuwgpu defenses --visible N --out RUN`): per "
        "defense and check schedule S (a check every S frames; empty: no periodic check), the frames drawn "
        "from a corrupted model that are catastrophic, and SDC (a visible change that is not catastrophic), "
        "per upset, exposure counted, with 95% bootstrap intervals over the upsets (no event: the exact "
        "binomial bound times the window). One upset of the dangerous cells per window of `window` frames, "
        "reloaded at its start, landing at a uniform frame; every arm on the same upsets at the same frames. "
        "after the check: the catastrophic frames that follow the check (the post-check residue; a defense "
        "without a check never repairs). x none: catastrophic frames over the unguarded arm's, paired. Every "
        "number grows with the window: the unguarded arm draws an upset until the reload."
    )
    cols = (["run"] if t["run"].nunique() > 1 else []) + list(COLUMNS)  # which folder, when several
    df = t[cols].rename(columns=COLUMNS)
    df["S"] = df["S"].map(lambda s: "" if s == 0 else str(int(s)))
    return TableItem("visible_damage", "What the user sees, per upset", df, cap), numbers
