"""The libraries the plain install leaves out (docs/install.md): scipy and scikit-learn (the
`analysis` extra), scikit-image (the `test` extra). Without them an analysis stops with one line
naming the extra, and the report lists exactly the sections that need them as skipped, with that
line's remedy, and keeps every other section. Run here with the libraries hidden from import."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest
from test_report import _dose_rows, _single_rows, write_run

from seuwgpu.analysis import stats
from seuwgpu.errors import MissingExtra, SeuwgpuError
from seuwgpu.metrics.image import numpy_metrics
from seuwgpu.report.build import load_runs
from seuwgpu.report.sections import run_sections

ANALYSIS = "pip install 'seuwgpu[analysis]'"


@pytest.fixture
def hide(monkeypatch):
    """hide("scipy", ...): those packages (and their loaded submodules) fail to import."""

    def hide(*tops):
        for name in list(sys.modules):
            if name.split(".")[0] in tops:
                monkeypatch.setitem(sys.modules, name, None)
        for top in tops:
            monkeypatch.setitem(sys.modules, top, None)

    return hide


def test_an_analysis_without_its_library_names_the_extra(hide):
    hide("scipy", "sklearn", "skimage")
    fit = stats.linear_fit([0, 1], [1, 3])  # two points: no interval, so no scipy needed
    assert fit.slope == pytest.approx(2.0) and np.isnan(fit.slope_lo)
    with pytest.raises(MissingExtra) as e:
        stats.linear_fit([0, 1, 2], [1, 3, 4])
    assert isinstance(e.value, SeuwgpuError) and isinstance(e.value, ImportError)
    assert str(e.value) == f"the slope's Student-t interval needs scipy, which the plain install leaves out: {ANALYSIS}"
    with pytest.raises(MissingExtra, match=r"the ROC AUC needs scikit-learn, .*seuwgpu\[analysis\]"):
        stats.auc([0, 1, 1], [0.1, 0.5, 0.9])
    frames = np.zeros((1, 8, 8, 3), np.float32)
    with pytest.raises(MissingExtra, match=r"image metrics needs scikit-image, .*pip install 'seuwgpu\[test\]'$"):
        numpy_metrics(frames, frames[None])


def test_the_report_skips_only_what_needs_the_analysis_extra(tmp_path, hide):
    rng = np.random.default_rng(3)
    single = pd.DataFrame(_single_rows(rng, per_cell=2))
    single = single[(single["precision"] == "fp32") & (single["scene"] == "lego")]  # small: seconds
    rows = pd.concat([single, pd.DataFrame(_dose_rows(rng))], ignore_index=True)
    df, manifests = load_runs([write_run(tmp_path / "run", rows, parts=1)])
    ctx = {"max_pred_rows": 5_000}
    full = [s.key for s in run_sections(df, manifests, ctx)]
    hide("scipy", "sklearn")
    lean_ctx = {"max_pred_rows": 5_000}
    lean = [s.key for s in run_sections(df, manifests, lean_ctx)]
    needs_extra = {label: (reason, remedy) for label, reason, remedy in lean_ctx["skipped"] if remedy == ANALYSIS}
    assert {"theory", "prediction", "dose"} <= set(full) - set(lean)
    assert len(needs_extra) == len(set(full) - set(lean))  # every section lost is one the extra brings back
    assert [k for k in full if k in lean] == lean  # the rest unchanged, in order
    assert all("scipy" in r or "scikit-learn" in r for r, _ in needs_extra.values())
    assert set(ctx["skipped"]) <= set(lean_ctx["skipped"])  # what lacked data still says so
