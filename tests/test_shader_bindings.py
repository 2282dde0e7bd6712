"""Binding numbers are kept by hand in the WGSL files, and a stage is compiled from several files
(`// #import`): two files that declare the same (group, binding) for different variables would
compile and bind the wrong buffer. This checks every stage as it is compiled, without a GPU."""

from pathlib import Path

import pytest

from seuwgpu.gpu.device import shader_files
from seuwgpu.gpu.kernel import wgsl_bindings

SHADERS = Path(__file__).resolve().parents[1] / "shaders"
STAGES = sorted(p.stem for p in SHADERS.glob("*.wgsl"))


def collisions(name: str, read=None) -> dict[tuple[int, int], list[str]]:
    """{(group, binding): ['file.wgsl:var', ...]} of the slots declared more than once in the files
    stage NAME is compiled from."""
    files = shader_files(name) if read is None else shader_files(name, read)
    slots: dict[tuple[int, int], list[str]] = {}
    for file, text in files:
        for var, slot in wgsl_bindings(text).items():
            slots.setdefault(slot, []).append(f"{file}.wgsl:{var}")
    return {slot: where for slot, where in slots.items() if len(where) > 1}


@pytest.mark.parametrize("stage", STAGES)
def test_no_binding_is_declared_twice_across_imports(stage):
    assert collisions(stage) == {}


def test_a_collision_across_imports_is_found():
    files = {
        "helper": "@group(0) @binding(3) var<storage, read> a: array<u32>;\n",
        "stage": "// #import helper\n@group(0) @binding(3) var<storage, read_write> b: array<u32>;\n"
        "@group(1) @binding(3) var<storage, read> c: array<u32>;\n",
    }
    assert collisions("stage", read=lambda n: files[n]) == {(0, 3): ["helper.wgsl:a", "stage.wgsl:b"]}
