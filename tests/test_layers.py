"""The package's layers (docs/architecture.md): each folder imports only itself and the folders
below it, no module imports itself back through others, and no module reaches into another
module's private names. Read from the source with `ast`, imports inside functions included."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "seuwgpu"

# Bottom to top. `errors` holds the project's exception types, `version` the package version
# alone; the package root (the public API) and `__main__` sit above everything.
LAYERS = [
    "errors",
    "version",
    "model",
    "gpu",
    "render",
    "metrics",
    "faults",
    "campaign",
    "analysis",
    "report",
    "api",
    "apps",
]
TOP = len(LAYERS)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {module_name(p): p for p in PACKAGE.rglob("*.py")}


def layer_of(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] == "__main__":
        return TOP
    return LAYERS.index(parts[1])


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str | None:
    if node.level == 0:
        return node.module
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(module: str) -> list[tuple[str, int, str | None]]:
    """(target module, line, imported name or None) for every seuwgpu import in `module`."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno, None) for a in node.names if a.name.split(".")[0] == "seuwgpu"]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(node, module, path.name == "__init__.py")
            if not target or target.split(".")[0] != "seuwgpu":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((sub, node.lineno, None) if sub in MODULES else (target, node.lineno, a.name))
    return out


def test_every_module_sits_in_a_known_layer():
    unknown = sorted(m for m in MODULES if m.count(".") >= 1 and m.split(".")[1] not in LAYERS + ["__main__"])
    assert not unknown, f"modules outside the layers {LAYERS}: {unknown}"


def test_imports_only_go_down():
    bad = []
    for m in MODULES:
        for target, line, _ in imports_of(m):
            if target in MODULES and layer_of(target) > layer_of(m):
                bad.append(f"{MODULES[m].relative_to(PACKAGE.parent)}:{line}: {m} imports {target}")
    assert not bad, "imports from a lower layer to a higher one:\n" + "\n".join(bad)


def test_no_import_circles():
    graph = {m: {t for t, _, _ in imports_of(m) if t in MODULES and t != m} for m in MODULES}
    # a package's __init__ may gather its own modules; those edges are not circles by themselves
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for m in sorted(graph):
        if m not in index:
            visit(m)
    assert not cycles, f"import circles: {cycles}"


# wgpu-py objects whose internals a module uses on purpose (the version is pinned in pyproject.toml):
# gpu/device.py `_wait` polls the device without blocking and reads a mapping promise's state, as
# wgpu-py's public API only waits for all queued work (see Readback).
WGPU_INTERNALS = {"seuwgpu.gpu.device": {("promise", "_state"), ("device", "_poll")}}


def _private_reach_ins(module: str) -> list[str]:
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    bad = []
    module_aliases, foreign = {}, set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            target = _resolve(node, module, path.name == "__init__.py")
            if not target or target.split(".")[0] != "seuwgpu":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in MODULES:
                    module_aliases[a.asname or a.name] = sub
                elif a.name.startswith("_") and not a.name.endswith("__") and target != module:
                    bad.append(f"{path.name}:{node.lineno}: imports {target}.{a.name}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name in MODULES and a.asname:
                    module_aliases[a.asname] = a.name
                elif a.name.split(".")[0] != "seuwgpu":
                    foreign.add(a.asname or a.name.split(".")[0])  # other libraries' own conventions
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")):
            continue
        owner = node.value
        if isinstance(owner, ast.Name) and (owner.id in ("self", "cls") or owner.id in foreign):
            continue
        if isinstance(owner, ast.Name) and (owner.id, node.attr) in WGPU_INTERNALS.get(module, ()):
            continue
        if isinstance(owner, ast.Call) and isinstance(owner.func, ast.Name) and owner.func.id == "super":
            continue
        if isinstance(owner, ast.Name) and owner.id in module_aliases and module_aliases[owner.id] != module:
            bad.append(f"{path.name}:{node.lineno}: {owner.id}.{node.attr} (module {module_aliases[owner.id]})")
        elif not (isinstance(owner, ast.Name) and owner.id in module_aliases):
            bad.append(f"{path.name}:{node.lineno}: {ast.unparse(owner)}.{node.attr}")
    return bad


def test_no_reach_ins_to_private_names():
    bad = [b for m in sorted(MODULES) for b in _private_reach_ins(m)]
    assert not bad, "private names used from outside their own object or module:\n" + "\n".join(bad)


@pytest.mark.parametrize("case", ["down", "circle", "private"])
def test_the_layer_checks_catch_violations(tmp_path, monkeypatch, case):
    """The checks above fail on a planted violation (so they are not vacuous)."""
    pkg = tmp_path / "seuwgpu"
    for d in ("model", "render"):
        (pkg / d).mkdir(parents=True)
        (pkg / d / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    src = {
        "down": {"model/a.py": "from seuwgpu.render import b\n", "render/b.py": ""},
        "circle": {
            "model/a.py": "from seuwgpu.model import c\n",
            "model/c.py": "def f():\n    from seuwgpu.model import a\n",
            "render/b.py": "",
        },
        "private": {"model/a.py": "", "render/b.py": "from seuwgpu.model import a\nx = a._hidden\n"},
    }[case]
    for name, text in src.items():
        (pkg / name).write_text(text)
    monkeypatch.setattr(__import__(__name__), "PACKAGE", pkg, raising=False)
    g = globals()
    monkeypatch.setitem(g, "PACKAGE", pkg)
    monkeypatch.setitem(g, "MODULES", {module_name(p): p for p in pkg.rglob("*.py")})
    check = {
        "down": test_imports_only_go_down,
        "circle": test_no_import_circles,
        "private": test_no_reach_ins_to_private_names,
    }[case]
    with pytest.raises(AssertionError):
        check()


def test_tests_import_their_helpers_by_module_name():
    """`from tests.conftest import ...` works under `python -m pytest` only (the repository root on
    sys.path); the `pytest` script puts just the tests folder there, so such a file stops the run
    at collection. Test helpers are imported as `conftest`, `test_x`."""
    tests = Path(__file__).resolve().parent
    bad = []
    for path in sorted(tests.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            names += [a.name for a in node.names] if isinstance(node, ast.Import) else []
            bad += [f"{path.name}: {n}" for n in names if n == "tests" or n.startswith("tests.")]
    assert not bad, bad
