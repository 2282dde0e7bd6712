"""gpu/kernel.py: Struct layouts against hand-computed WGSL offsets, the constants header, and the
Kernel's bind-group cache and dispatch grid."""

import gc

import numpy as np
import pytest

from seuwgpu.gpu.constants import MAX_GROUPS_X, PRECISION_CODE, TILE, UNIFORM_STRIDE, WG, wgsl_header
from seuwgpu.gpu.device import UNIFORM, shader_files, shader_imports, shader_source
from seuwgpu.gpu.kernel import (
    Kernel,
    Struct,
    Uniforms,
    entry_bindings,
    wgsl_bindings,
    wgsl_constants,
    workgroup_size,
)

LAYOUT_SRC = """
const N: u32 = 3u;
struct Inner {
    a: f32,
    b: vec2<f32>,       // align 8: offset 8
};
struct Outer {
    x: u32,             // 0
    v3: vec3<f32>,      // align 16: 16 .. 28
    y: u32,             // packs into the vec3's tail: 28
    v2: vec2f,          // 32
    m: mat4x4<f32>,     // align 16: 48 .. 112
    arr: array<u32, 4>, // 112 .. 128
    inner: Inner,       // align 8, size 16: 128 .. 144
    vs: array<vec4<i32>, N>, // 144 .. 192
    @align(16) z: f32,  // 192
    @size(8) w: u32,    // 196 .. 204
    tail_pad: u32,      // 204; struct size rounds 208 up to align 16 -> 208
};
struct Header {
    count: u32,
    recs: array<Inner>, // runtime-sized tail at roundUp(4, align 8) = 8, after an 8-byte header
};
"""


def test_struct_layout_follows_wgsl_alignment_rules():
    s = Struct.from_wgsl(LAYOUT_SRC, "Outer")
    want = {
        "x": 0,
        "v3": 16,
        "y": 28,
        "v2": 32,
        "m": 48,
        "arr": 112,
        "inner": 128,
        "vs": 144,
        "z": 192,
        "w": 196,
        "tail_pad": 204,
    }
    assert {f: s.offset(f) for f in s.fields} == want
    assert s.size == 208
    inner = Struct.from_wgsl(LAYOUT_SRC, "Inner")
    assert (inner.size, inner.offset("b")) == (16, 8)
    assert s.zeros()["m"].shape == (4, 4) and s.zeros()["vs"].shape == (3, 4)
    h = Struct.from_wgsl(LAYOUT_SRC, "Header")
    assert h.size == 8 and h.tail[0] == "recs" and h.offset("recs") == 8 and h.tail[2].itemsize == 16


def test_struct_bytes_land_where_the_shader_reads_them():
    s = Struct.from_wgsl(LAYOUT_SRC, "Outer")
    m = np.arange(16, dtype=np.float32).reshape(4, 4)
    raw = s.pack(x=7, y=9, v3=[1, 2, 3], m=m, inner=(5.0, [6.0, 7.0])).view(np.uint32)
    f = raw.view(np.float32)
    assert raw[0] == 7 and raw[7] == 9 and f[4:7].tolist() == [1, 2, 3]
    assert f[12:28].tolist() == m.reshape(-1).tolist()  # column by column: m[col][row]
    assert f[32] == 5.0 and f[34:36].tolist() == [6.0, 7.0]
    assert raw.size * 4 == s.size
    with pytest.raises(KeyError, match="no field 'count'"):
        s.pack(count=1)


def test_struct_from_a_numpy_dtype_and_uniform_slots(gpu):
    s = Struct(np.dtype([("a", "<u4"), ("b", "<f4")]), "Pair")
    assert s.size == 8 and s.offset("b") == 4
    u = Uniforms(gpu, Struct.from_shader("flip", "FlipParams"), 3)
    assert u.rows.dtype.itemsize == UNIFORM_STRIDE and u.buffer.size == 3 * UNIFORM_STRIDE
    assert u.binding(2) == (u.buffer, 2 * UNIFORM_STRIDE, 16)
    with pytest.raises(ValueError):
        Struct(np.dtype("<u4"))


def test_shader_structs_match_the_host_layouts_they_replace():
    """The offsets the host used to write by hand, now read from the shaders."""
    view = Struct.from_shader("project", "View")
    assert view.size == 176
    assert [view.offset(f) for f in ("campos", "intr", "background", "width", "fmt", "guard_hi", "tile_x0")] == [
        64,
        80,
        96,
        112,
        148,
        160,
        164,
    ]
    binning = Struct.from_shader("bin", "Binning")
    assert (binning.size, binning.offset("origin"), binning.offset("background")) == (64, 28, 48)
    assert (binning.offset("views"), binning.offset("frame")) == (32, 36)  # vec4 background aligned to 16
    rec = Struct.from_shader("metrics", "MetricsRecord")
    assert rec.size == 24 and rec.fields == ("changed", "peak", "sse", "nonfinite", "deficit", "count")
    assert Struct.from_shader("metrics", "MetricsResults").offset("records") == 16


def test_unsupported_types_are_refused():
    with pytest.raises(ValueError, match="unsupported"):
        Struct.from_wgsl("struct S { b: bool, };", "S")
    with pytest.raises(ValueError, match="padded"):
        Struct.from_wgsl("struct S { a: array<vec3<f32>, 2>, };", "S")
    with pytest.raises(ValueError, match="no `struct T`"):
        Struct.from_wgsl("struct S { a: u32, };", "T")


def test_constants_header_defines_the_shared_values_once():
    head = wgsl_header({"EXTRA": 5})
    assert f"const TILE: u32 = {TILE}u;" in head and "const EXTRA: u32 = 5u;" in head
    for p, code in PRECISION_CODE.items():
        assert f"const FMT_{p.upper()}: u32 = {code}u;" in head
    src = shader_source("composite")
    values = wgsl_constants(src)
    assert values["TILE_PIXELS"] == TILE * TILE and values["MAX_GROUPS_X"] == MAX_GROUPS_X
    assert values["LANES"] == TILE * TILE // 8  # 8 pixels per invocation
    assert workgroup_size(src, "main") == (TILE, TILE // 8, 1)
    assert workgroup_size(shader_source("scan"), "ps_reduce") == (WG, 1, 1)
    assert workgroup_size(shader_source("metrics"), "tile_partials") == (TILE * TILE // 4, 1, 1)
    with pytest.raises(ValueError):
        workgroup_size(src, "no_such_entry")


def test_kernel_caches_bind_groups_by_what_they_bind(gpu):
    k = Kernel(gpu, "flip")
    assert k.workgroup_size == (WG, 1, 1) and k.label == "flip:main"
    params = gpu.upload(k.struct("FlipParams").pack(count=0), UNIFORM)
    a, b, words = gpu.buffer(64), gpu.buffer(64), gpu.buffer(64)
    (bg,) = k.bind(params=params, flips=a, words=words)
    assert k.bind({"params": params, "flips": a, "words": words})[0] is bg  # a mapping, in any order
    assert k.bind({"words": words}, params=params, flips=a)[0] is bg
    assert k.bind(params=(params, 0, 16), flips=a, words=words)[0] is not bg  # a range is another binding
    (other,) = k.bind(params=params, flips=b, words=words)
    assert other is not bg and k.cached_bind_groups == 3
    assert len(k._named) == 4  # the calls by name, one per order of names: two resolve to `bg`
    del a  # a collected buffer takes its bind groups with it: no stale entry, nothing pinned
    gc.collect()
    assert k.cached_bind_groups == 1 and k.bind(params=params, flips=b, words=words)[0] is other
    assert len(k._named) == 1  # the by-name entries of `a` went too (they hold its bind groups)
    del params, b, words, bg, other
    gc.collect()
    assert k.cached_bind_groups == 0 and not k._named and not k._keys_of


BINDINGS_SRC = """
@group(0) @binding(0) var<uniform> params: P;
@binding(2) @group(1) var<storage, read_write> out: array<u32>;   // attributes in either order
@group(0) @binding(1) var<storage, read> table: array<f32>;
@group(0) @binding(3) var<storage, read> unused_here: array<f32>;
// @group(0) @binding(9) var<storage, read> commented_out: array<u32>;
fn helper(i: u32) -> f32 { return table[i]; }
fn other() -> f32 { return unused_here[0]; }
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    out[id.x] = u32(helper(id.x) * f32(params.table));   // `.table` is a member, not a use
}
@compute @workgroup_size(64)
fn second() { out[0] = u32(other()); }
"""


def test_bindings_are_read_from_the_shader_with_their_static_use():
    assert wgsl_bindings(BINDINGS_SRC) == {"params": (0, 0), "out": (1, 2), "table": (0, 1), "unused_here": (0, 3)}
    assert list(entry_bindings(BINDINGS_SRC, "main")) == ["params", "table", "out"]  # via helper()
    assert list(entry_bindings(BINDINGS_SRC, "second")) == ["unused_here", "out"]  # by (group, binding)
    with pytest.raises(ValueError, match="no entry point 'third'"):
        entry_bindings(BINDINGS_SRC, "third")
    # every stage's entry points bind what their shader declares, e.g. the merge pass
    merge = entry_bindings(shader_source("composite"), "merge")
    assert list(merge) == ["bin", "ranges", "image", "chunk_slabs", "merge_list", "work_counts"]


def test_binding_by_an_unknown_or_a_missing_name_is_a_clear_error(gpu):
    k = Kernel(gpu, "flip")
    assert list(k.expects) == ["params", "flips", "words"]
    a = gpu.buffer(64)
    enc = gpu.device.create_command_encoder()
    with pytest.raises(KeyError, match=r"kernel flip:main has no binding 'pairs' \(it expects: params, flips, words\)"):
        k.dispatch(enc, params=a, pairs=a, words=a, threads=1)
    with pytest.raises(KeyError, match=r"kernel flip:main is missing binding\(s\) flips, words \(it expects"):
        k.dispatch(enc, params=a, threads=1)
    with pytest.raises(KeyError, match="has no binding 0"):  # the numbered form is gone
        k.bind({0: a, 1: a, 2: a})
    # a name the shader declares but this entry point does not use is passed over
    merge = Kernel(gpu, "composite", "merge")
    assert "proj_rgb" in merge.declared and "proj_rgb" not in merge.expects
    with pytest.raises(KeyError, match=r"composite:merge is missing binding\(s\) ranges, image"):
        merge.resolve(bin=a, proj_rgb=a, chunk_slabs=a, merge_list=a, work_counts=a)


def _reader(files: dict):
    def read(name):
        if name not in files:
            raise FileNotFoundError(name)
        return files[name]

    return read


def test_imports_resolve_depth_first_each_file_once_in_order():
    files = {
        "base": "// base\nconst A: u32 = 1u;\n",
        "left": "// #import base\n\n// left: needs base\nconst L: u32 = A;\n",
        "right": "// #import base\n// #import left\nconst R: u32 = L;\n",
        "stage": "// #import left\n// #import right\n// #import base\n\nconst S: u32 = R;\n",
    }
    order = shader_files("stage", read=_reader(files))
    assert [n for n, _ in order] == ["base", "left", "right", "stage"]  # base once, before its users
    assert [t for _, t in order] == [files[n] for n in ("base", "left", "right", "stage")]


def test_a_missing_import_or_a_cycle_is_a_clear_error():
    files = {"stage": "// #import mid\n", "mid": "// #import gone\n"}
    with pytest.raises(
        FileNotFoundError, match=r"shaders/gone.wgsl does not exist \(imported by stage.wgsl -> mid.wgsl\)"
    ):
        shader_files("stage", read=_reader(files))
    cycle = {"stage": "// #import a\n", "a": "// #import b\n", "b": "// #import a\n"}
    with pytest.raises(ValueError, match=r"cycle: a.wgsl -> b.wgsl -> a.wgsl"):
        shader_files("stage", read=_reader(cycle))
    with pytest.raises(ValueError, match="line 3: #import below the first declaration"):
        shader_imports("// #import a\nconst X: u32 = 1u;\n// #import b\n", "late")
    with pytest.raises(ValueError, match=r"line 1: #import takes one shader name, not 'blend  \(and common\)'"):
        shader_imports("// #import blend  (and common)\n", "noted")


def test_stages_compile_from_their_declared_imports():
    """The compositors name what they share; every stage imports common.wgsl."""
    assert [n for n, _ in shader_files("composite_wide")] == ["common", "blend", "composite_frame", "composite_wide"]
    assert [n for n, _ in shader_files("flip")] == ["common", "flip"]
    src = shader_source("composite")
    assert src.count("fn blend_quad(") == 1 and src.count("fn chunks(") == 1  # blend, composite_frame once


def test_kernel_grid_splits_long_1d_dispatches(gpu):
    k = Kernel(gpu, "flip")
    assert k.grid(0) == (1, 1, 1) and k.grid(WG) == (1, 1, 1) and k.grid(WG + 1) == (2, 1, 1)
    assert k.grid(WG * MAX_GROUPS_X) == (MAX_GROUPS_X, 1, 1)
    assert k.grid(WG * MAX_GROUPS_X + 1) == (MAX_GROUPS_X, 2, 1)
    enc = gpu.device.create_command_encoder()
    with pytest.raises(ValueError, match="threads, workgroups or indirect"):
        k.dispatch(enc, {})


def test_steady_state_work_creates_no_bind_group(gpu, monkeypatch):
    """Once warm, rendering, injecting and incremental evaluation only look bind groups up."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model.scenes import make_scene, scene_cameras

    eng = Engine(make_scene("spheres", n=800, seed=1), scene_cameras("spheres", 2, 40, 32), "fp32")
    sites = [eng.site("log_scales", p, 0, 31) for p in (3, 50, 400)]

    def work():
        eng.renderer.render()
        eng.inject(sites[0], "guard")
        eng.evaluate(sites, ("none", "ecc"))

    work()
    made = []
    real = gpu.bind
    monkeypatch.setattr(gpu, "bind", lambda *a, **kw: made.append(a) or real(*a, **kw))
    work()
    work()
    assert made == []


def test_binding_limit_is_floored_to_the_buffer_granularity(gpu, monkeypatch):
    """NVIDIA reports 2**31 - 4 bytes per binding; buffers are bound whole and sized in 16-byte
    steps, so the usable limit is 2**31 - 16 (a 2**29-entry list rounded to 2**31 bytes, over it)."""
    monkeypatch.setitem(gpu.limits, "max-storage-buffer-binding-size", 2**31 - 4)
    monkeypatch.setitem(gpu.limits, "max-buffer-size", 2**32 - 2**21)
    assert gpu.max_binding == 2**31 - 16
    largest_list = 4 * (gpu.max_binding // 4)  # the renderer's intersection capacity, in bytes
    assert -(-largest_list // 16) * 16 <= 2**31 - 4
    monkeypatch.setitem(gpu.limits, "max-storage-buffer-binding-size", 1 << 27)  # lavapipe's
    assert gpu.max_binding == 1 << 27


def test_readback_returns_the_copy_of_its_own_submission(gpu):
    """gpu/device.py Readback: the bytes as they were when its submission ran (not later writes),
    two readbacks in flight each with their own, and a copy larger than the buffer grows it."""
    from seuwgpu.gpu.device import STORAGE, Readback

    src = gpu.upload(np.arange(64, dtype=np.uint32), STORAGE, "src")
    a, b = Readback(gpu, 64, "a"), Readback(gpu, 16, "b")
    enc = gpu.device.create_command_encoder()
    a.encode(enc, src, 16, 64)  # words 4..19
    gpu.submit(enc)
    gpu.write(src, np.full(64, 7, np.uint32))  # lands after the first submission
    enc = gpu.device.create_command_encoder()
    b.encode(enc, src, 0, 256)  # grows to 256 bytes
    gpu.submit(enc)
    np.testing.assert_array_equal(a.read(np.uint32), np.arange(4, 20, dtype=np.uint32))
    np.testing.assert_array_equal(b.read(np.uint32), np.full(64, 7, np.uint32))
    assert b.buffer.size >= 256
    # read again after a new copy: the buffer was unmapped, and an empty copy reads nothing
    enc = gpu.device.create_command_encoder()
    a.encode(enc, src, 0, 8)
    b.encode(enc, src, 0, 0)
    gpu.submit(enc)
    np.testing.assert_array_equal(a.read(np.uint32), [7, 7])
    assert b.read(np.uint32).size == 0


def test_const_reads_the_value_the_pipeline_was_compiled_with(gpu):
    """Kernel.const: a const by name; an override as this kernel's pipeline constants set it (and
    what derives from it), not the shader's default; an unknown name is a clear error."""
    from seuwgpu.gpu.sort import SCAN_PLAN

    src = shader_source("scan", SCAN_PLAN)
    default = wgsl_constants(src)
    per = 4 if default["PS_PER"] != 4 else 8
    k = Kernel(gpu, "scan", "ps_reduce", constants={"PS_PER": per}, defines=SCAN_PLAN)
    assert k.const("PS_PER") == per != default["PS_PER"]
    assert k.const("PS_BLOCK") == k.const("WG") * per  # PS_BLOCK = WG * PS_PER in scan.wgsl
    assert Kernel(gpu, "scan", "ps_reduce", defines=SCAN_PLAN).const("PS_PER") == default["PS_PER"]
    with pytest.raises(KeyError, match="no integer const 'PS_NOPE'"):
        k.const("PS_NOPE")
