"""The API reference and the example notebook cannot go stale: both are rebuilt here."""

from __future__ import annotations

import importlib.util
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(f"tools_{name}", ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_public_name_is_documented():
    from seuwgpu import api

    for name in api.__all__:
        obj = getattr(api, name)
        if callable(obj):
            assert (inspect.getdoc(obj) or "").strip(), f"seuwgpu.{name} has no docstring"
            if inspect.isfunction(obj):
                hints = inspect.get_annotations(obj)
                assert "return" in hints, f"seuwgpu.{name} has no return type hint"
                params = [p for p in inspect.signature(obj).parameters.values() if p.kind != p.VAR_KEYWORD]
                assert all(p.name in hints for p in params), f"seuwgpu.{name}: a parameter without type hint"


def test_api_reference_is_current(tmp_path):
    built = _tool("build_docs").build(tmp_path / "api")
    committed = ROOT / "docs" / "api"
    names = sorted(p.relative_to(tmp_path / "api").as_posix() for p in built)
    assert names == sorted(p.relative_to(committed).as_posix() for p in committed.rglob("*") if p.is_file())
    for p in built:
        rel = p.relative_to(tmp_path / "api")
        assert p.read_bytes() == (committed / rel).read_bytes(), f"docs/api/{rel} is stale: run tools/build_docs.py"
    page = (committed / "seuwgpu" / "api.html").read_text()
    from seuwgpu import api

    # each public name has its own entry (its anchor, the whole name: `inject` is not found in
    # `Injection`'s entry)
    missing = [name for name in api.__all__ if not re.search(rf'\sid="{re.escape(name)}"', page)]
    assert not missing, f"no entry in docs/api for {missing}"


def test_committed_notebook_is_these_cells_executed():
    import nbformat

    nb = nbformat.read(ROOT / "docs" / "example.ipynb", as_version=4)
    cells = _tool("notebook").CELLS
    assert [(c.cell_type, c.source) for c in nb.cells] == [(k, s) for k, s in cells], "run tools/notebook.py"
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.execution_count for c in code), "the committed notebook is not executed"
    outputs = [o for c in code for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum("image/png" in o.get("data", {}) for o in outputs) >= 3


@pytest.mark.slow
def test_notebook_runs(tmp_path):
    nbtool = _tool("notebook")
    nb = nbtool.execute(nbtool.notebook(), small=True)
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum("image/png" in o.get("data", {}) for o in outputs) >= 3
    text = "".join(o.get("text", "") for o in outputs)
    assert "leica-sofort" in text and "injections" in text


def test_api_docstring_campaign_spec_is_a_valid_spec():
    """The module docstring's `run_campaign({...}, ...)` spec dict, completed with a [single]
    table, is one the spec checker takes (it showed "scenes": ["spheres"], refused as
    "scenes[0] must be a table")."""
    import ast

    from seuwgpu import api
    from seuwgpu.campaign.spec import normalize_spec

    found = re.search(r"run_campaign\((\{.*?), \.\.\.\}", api.__doc__)
    assert found, "the docstring no longer shows a run_campaign spec dict"
    spec = ast.literal_eval(found.group(1) + "}")
    normalize_spec({**spec, "single": {}})


def test_spec_docstring_is_a_valid_spec(tmp_path):
    """README: "See the docstring of seuwgpu/campaign/spec.py for every key". Read as TOML (its
    camera file written here), it is a spec the checker takes, each key in its table: `lpips =
    true` stood under [dose], where TOML puts it in that table ("unknown key 'lpips' in dose")."""
    import json
    import textwrap
    import tomllib

    from seuwgpu.campaign import spec as spec_module
    from seuwgpu.model.scenes import scene_cameras

    raw = tomllib.loads(textwrap.dedent(spec_module.__doc__.split("naming the key):\n", 1)[1]))
    orbits = {**raw, "scenes": [{k: v for k, v in raw["scenes"][0].items() if k != "cameras"}]}
    assert spec_module.normalize_spec(orbits).lpips is True
    del raw["size"]  # the docstring: a camera file's views keep their sizes, not with size =
    cams = [
        {"viewmat": c.viewmat.tolist(), "K": c.K.tolist(), "width": c.width, "height": c.height}
        for c in scene_cameras("spheres", 4, 64, 64)
    ]
    (tmp_path / raw["scenes"][0]["cameras"]).write_text(json.dumps({"cameras": cams}))
    spec = spec_module.normalize_spec(raw, base_dir=tmp_path)
    assert spec.lpips is True and spec.dose.repeats == raw["dose"]["repeats"]


def test_readme_minimal_spec_is_a_valid_spec():
    """The README's minimal campaign spec ("Campaign specs") is one `seuwgpu plan` takes."""
    import tomllib

    from seuwgpu.campaign.spec import normalize_spec

    text = (ROOT / "README.md").read_text()
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block, "the README shows no TOML spec"
    spec = normalize_spec(tomllib.loads(block.group(1)))
    assert spec.scenes[0].scene == "spheres" and spec.sizes is not None


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces to -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize(
    "page",
    ["README.md", "CONTRIBUTING.md", *sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md"))],
)
def test_every_relative_link_resolves(page):
    """The README sends readers to docs/ pages for what it no longer holds: every relative link
    of the README, CONTRIBUTING and the docs/ pages names a file that exists and, with #anchor, a
    heading of that file."""
    source = ROOT / page
    text = re.sub(r"```.*?```", "", source.read_text(), flags=re.S)  # links only outside code
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue  # http(s), mailto
        path, _, anchor = target.partition("#")
        linked = (source.parent / path).resolve() if path else source
        assert linked.exists(), f"{page}: link to {target}: no {linked.relative_to(ROOT)}"
        if anchor and linked.suffix == ".md":
            headings = re.findall(r"^#+ (.+)$", re.sub(r"```.*?```", "", linked.read_text(), flags=re.S), re.M)
            assert anchor in {github_anchor(h) for h in headings}, f"{page}: link to {target}: no such heading"
