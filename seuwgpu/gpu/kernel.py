"""Kernel (one compute entry point: pipeline, cached bind groups, dispatch) and Struct (a uniform
or record layout declared once, in the shader, and packed from Python).

Every GPU stage records its work through a Kernel and packs its parameters through a Struct, so
the pipeline set-up, the bind-group cache and the byte layout of a uniform exist once.

Constants shared by host and shader
-----------------------------------
Values both sides need (the tile size, the precision codes, workgroup sizes, dispatch-row
length) are Python values in gpu/constants.py, compiled into every shader as a generated header
of WGSL `const` declarations (`shader_source` prepends it): shaders use the names, Python imports
them, nobody restates the numbers. A stage may add its own header constants (`defines`, e.g. the
word positions of the sort's plan buffer that its host code also reads). Pipeline-overridable
constants (WGSL `override`, the `constants` argument) are kept for what varies between pipelines
of one shader: the sort's elements per thread, and variants of a kernel that a later stage may
specialise (a Kernel per override set; pipelines are cached per set). `const` is chosen over
`override` for the shared values because WGSL accepts consts everywhere (array sizes of
workgroup memory, `@workgroup_size`) and a missing override would silently take its default.

Structs
-------
`Struct.from_shader("project", "View")` parses the WGSL `struct View` of the compiled source and
lays it out with WGSL's host-shareable rules (u32/i32/f32 size 4; vec2 align 8; vec3 align 16,
size 12; vec4 align 16; matCxR as C columns of vecR; array<T, N> with stride
roundUp(align(T), size(T)); nested structs; @align/@size), so host and shader cannot disagree.
`Struct(dtype)` takes a numpy structured dtype instead, for a layout no shader declares. Records
are numpy structured arrays: fields by name, never word offsets. `Uniforms` holds slots of one
Struct UNIFORM_STRIDE bytes apart in one uniform buffer (one slot per view, chunk, ...).

Bindings by name
----------------
A kernel binds its buffers by the names the shader declares them under:
`@group(0) @binding(3) var<storage, read> rects: array<vec2<u32>>;` is bound as `rects=buf` (or
`rects=(buf, offset, size)` for a range), in keywords or a {name: buffer} mapping. The kernel
reads every declaration of its compiled source (`wgsl_bindings`) and which of them its entry
point uses (`entry_bindings`: the globals its body and the functions it calls name), so a name
the shader does not declare, or one the entry point uses and the call leaves out, is an error
naming the kernel and the names it expects. A declared name the entry point does not use is
passed over (stages share one set of buffers across their entry points).

Bind groups
-----------
`Kernel.bind` caches bind groups by what they bind: (binding, buffer identity, offset, size).
A buffer that is replaced (a new object) gives a new key, so nothing is invalidated by hand;
when a buffer is garbage-collected, the bind groups holding it are dropped (a weakref callback),
so a cache entry never outlives its buffers nor pins their memory. Steady-state encoding creates
no bind group.
"""

from __future__ import annotations

import ast
import functools
import re
import weakref

import numpy as np

from seuwgpu.gpu.constants import SHARED, UNIFORM_STRIDE
from seuwgpu.gpu.device import GPU, UNIFORM, dispatch_dims, shader_source


# ------------------------------------------------------------------------------------------------
# WGSL source: constants and struct layouts
# ------------------------------------------------------------------------------------------------
def _strip_comments(src: str) -> str:
    src = re.sub(r"/\*.*?\*/", " ", src, flags=re.S)
    return re.sub(r"//[^\n]*", "", src)


_INT_OPS = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a // b,  # WGSL integer division truncates (operands here are >= 0)
    ast.Mod: lambda a, b: a % b,
}


def _eval_int(expr: str, values: dict) -> int | None:
    """Integer value of a WGSL const expression of integer literals, known names, + - * / % and
    parentheses; None for anything else (floats, vectors, calls, unknown names)."""
    expr = re.sub(r"\b(\d+)[ui]\b", r"\1", expr.strip())  # literal suffixes: 4u -> 4

    def ev(node):
        if isinstance(node, ast.Constant) and type(node.value) is int:
            return node.value
        if isinstance(node, ast.Name) and node.id in values:
            return int(values[node.id])
        if isinstance(node, ast.BinOp) and type(node.op) in _INT_OPS:
            left, right = ev(node.left), ev(node.right)
            return None if left is None or right is None else _INT_OPS[type(node.op)](left, right)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            v = ev(node.operand)
            return None if v is None else -v
        return None

    try:
        return ev(ast.parse(expr, mode="eval").body)
    except (SyntaxError, ZeroDivisionError):
        return None


def wgsl_constants(src: str, overrides: dict | None = None) -> dict:
    """Integer `const` and `override` values declared in a WGSL source (`overrides` replace the
    overrides' defaults), in declaration order; non-integer ones are left out."""
    values = dict(SHARED)
    decl = r"\b(const|override)\s+(\w+)\s*(?::\s*[\w<>]+)?\s*=\s*([^;]+);"
    for kind, name, expr in re.findall(decl, _strip_comments(src)):
        if kind == "override" and overrides and name in overrides:
            values[name] = int(overrides[name])
            continue
        v = _eval_int(expr, values)
        if v is not None:
            values[name] = v
    for name in overrides or {}:
        values.setdefault(name, int(overrides[name]))
    return values


def workgroup_size(src: str, entry: str, overrides: dict | None = None) -> tuple[int, int, int]:
    """`@workgroup_size` of entry point `entry` in a WGSL source, evaluated."""
    code = _strip_comments(src)
    m = re.search(r"@workgroup_size\s*\(([^)]*)\)[^{;]*?\bfn\s+" + re.escape(entry) + r"\s*\(", code)
    if not m:
        raise ValueError(f"no @workgroup_size for entry point {entry!r}")
    values = wgsl_constants(code, overrides)
    dims = [_eval_int(d, values) for d in m.group(1).split(",") if d.strip()]
    if None in dims:
        raise ValueError(f"cannot evaluate @workgroup_size({m.group(1)}) of {entry!r}")
    return tuple(dims + [1] * (3 - len(dims)))


def wgsl_bindings(src: str) -> dict[str, tuple[int, int]]:
    """{name: (group, binding)} of every `@group(g) @binding(b) var<...> NAME` of a WGSL source."""
    decl = r"((?:@\w+\s*\(\s*\d+\s*\)\s*)+)var\b(?:\s*<[^>]*>)?\s+(\w+)"
    out = {}
    for attrs, name in re.findall(decl, _strip_comments(src)):
        at = dict(re.findall(r"@(\w+)\s*\(\s*(\d+)\s*\)", attrs))
        if "group" in at and "binding" in at:
            out[name] = (int(at["group"]), int(at["binding"]))
    return out


def _functions(code: str) -> dict[str, str]:
    """{name: parameters and body} of every `fn` of a comment-free WGSL source."""
    out = {}
    for m in re.finditer(r"\bfn\s+(\w+)\s*\(", code):
        start = code.find("{", m.end())
        depth, i = 0, start
        while i < len(code):
            depth += {"{": 1, "}": -1}.get(code[i], 0)
            if depth == 0:
                break
            i += 1
        out[m.group(1)] = code[m.end() : i + 1]
    return out


def entry_bindings(src: str, entry: str) -> dict[str, tuple[int, int]]:
    """The bindings (as wgsl_bindings gives them) that entry point `entry` uses: the globals named
    in its body or in the bodies of the functions it calls, transitively (WGSL's static use, which
    decides what an automatic layout holds). A member access `x.name` is not a use of `name`."""
    code = _strip_comments(src)
    declared, functions = wgsl_bindings(code), _functions(code)
    if entry not in functions:
        raise ValueError(f"no entry point {entry!r} in the shader source")
    used, todo, seen = set(), [entry], set()
    while todo:
        fn = todo.pop()
        if fn in seen:
            continue
        seen.add(fn)
        for word in set(re.findall(r"(?<![\w.])[A-Za-z_]\w*", functions[fn])):
            if word in declared:
                used.add(word)
            elif word in functions:
                todo.append(word)
    return {name: declared[name] for name in sorted(used, key=declared.get)}


_SCALARS = {"u32": "<u4", "i32": "<i4", "f32": "<f4"}
_SHORT = {"f": "f32", "u": "u32", "i": "i32"}


def _split_top(text: str, sep: str = ",") -> list[str]:
    """Split at `sep` outside <...> and (...)."""
    out, depth, cur = [], 0, ""
    for ch in text:
        if ch in "<(":
            depth += 1
        elif ch in ">)":
            depth -= 1
        if ch == sep and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    if cur.strip():
        out.append(cur)
    return out


class _Layout:
    """WGSL size, alignment and numpy dtype of host-shareable types of one source."""

    def __init__(self, src: str):
        self.src = _strip_comments(src)
        self.values = wgsl_constants(self.src)
        self.bodies = dict(re.findall(r"\bstruct\s+(\w+)\s*\{([^}]*)\}", self.src))
        self.structs: dict[str, tuple[int, int, np.dtype]] = {}
        self.tails: dict[str, tuple[str, int, np.dtype]] = {}  # runtime-sized last members

    def of(self, t: str) -> tuple[int, int, np.dtype]:
        """(size, align, dtype) of WGSL type `t`."""
        t = t.strip()
        if t in _SCALARS:
            return 4, 4, np.dtype(_SCALARS[t])
        m = re.fullmatch(r"atomic\s*<\s*(\w+)\s*>", t)
        if m:
            return self.of(m.group(1))
        m = re.fullmatch(r"vec([234])\s*(?:<\s*(\w+)\s*>|([fui]))", t)
        if m:
            n, scalar = int(m.group(1)), m.group(2) or _SHORT[m.group(3)]
            return 4 * n, (8 if n == 2 else 16), np.dtype((_SCALARS[scalar], (n,)))
        m = re.fullmatch(r"mat([234])x([234])\s*(?:<\s*f32\s*>|f)", t)
        if m:
            cols, rows = int(m.group(1)), int(m.group(2))
            col_align = 8 if rows == 2 else 16
            stride = -(-4 * rows // col_align) * col_align  # a vec3 column is padded to 16 bytes
            # [column][row], padded columns (mat3) keep their padding word as a 4th row
            return cols * stride, col_align, np.dtype(("<f4", (cols, stride // 4)))
        m = re.fullmatch(r"array\s*<(.*)>", t, flags=re.S)
        if m:
            parts = _split_top(m.group(1))
            if len(parts) != 2:
                raise ValueError(f"runtime-sized {t} has no fixed host layout: describe its element struct")
            size, align, dt = self.of(parts[0])
            count = _eval_int(parts[1], self.values)
            if count is None:
                raise ValueError(f"cannot evaluate the length of {t}")
            stride = -(-size // align) * align
            if stride != size:
                raise ValueError(f"{t}: elements of {size} bytes padded to {stride}; pad the element type instead")
            return count * stride, align, np.dtype((dt, (count,)))
        if t in self.bodies:
            return self.struct(t)
        raise ValueError(f"unsupported WGSL type {t!r} in a host-shared struct")

    def struct(self, name: str) -> tuple[int, int, np.dtype]:
        if name in self.structs:
            return self.structs[name]
        if name not in self.bodies:
            raise ValueError(f"no `struct {name}` in the shader source")
        names, formats, offsets = [], [], []
        offset, struct_align = 0, 1
        members = _split_top(self.bodies[name])
        for i, member in enumerate(members):
            m = re.fullmatch(r"\s*((?:@\w+\s*\(\s*\d+\s*\)\s*)*)(\w+)\s*:\s*(.+?)\s*", member, flags=re.S)
            if not m:
                raise ValueError(f"cannot parse member {member.strip()!r} of struct {name}")
            attrs = dict(re.findall(r"@(\w+)\s*\(\s*(\d+)\s*\)", m.group(1)))
            runtime = re.fullmatch(r"array\s*<([^,]*)>", m.group(3).strip(), flags=re.S)
            if runtime and i == len(members) - 1:  # a storage struct's runtime-sized tail
                esize, ealign, edt = self.of(runtime.group(1))
                offset = -(-offset // ealign) * ealign
                self.tails[name] = (m.group(2), offset, edt)
                struct_align = max(struct_align, ealign)
                break
            size, align, dt = self.of(m.group(3))
            align = int(attrs.get("align", align))
            size = int(attrs.get("size", size))
            offset = -(-offset // align) * align
            names.append(m.group(2))
            formats.append(dt)
            offsets.append(offset)
            offset += size
            struct_align = max(struct_align, align)
        size = -(-offset // struct_align) * struct_align
        dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size})
        self.structs[name] = (size, struct_align, dt)
        return self.structs[name]


# ------------------------------------------------------------------------------------------------
# Struct
# ------------------------------------------------------------------------------------------------
class Struct:
    """A record layout: a numpy structured dtype whose field offsets and size are the WGSL ones."""

    def __init__(self, dtype, name: str = "", align: int = 16, tail: tuple | None = None):
        """`tail`: (name, byte offset, element dtype) of a runtime-sized last member, whose
        records follow the fixed part (a storage buffer's header-then-array layout)."""
        self.dtype = np.dtype(dtype)
        if self.dtype.names is None:
            raise ValueError("a Struct needs a structured dtype (named fields)")
        self.name = name or "record"
        self.size = self.dtype.itemsize
        self.align = int(align)
        self.tail = tail

    @classmethod
    def from_wgsl(cls, source: str, name: str) -> Struct:
        """`struct NAME` of a WGSL source (constants it uses for array lengths declared in it or
        shared through gpu/constants.py)."""
        layout = _Layout(source)
        size, align, dt = layout.struct(name)
        return cls(dt, name, align, layout.tails.get(name))

    @classmethod
    def from_shader(cls, shader: str, name: str, defines: dict | None = None) -> Struct:
        """`struct NAME` as shaders/SHADER.wgsl is compiled (header, its imports, the file)."""
        return _shader_struct(shader, name, tuple(sorted((defines or {}).items())))

    @property
    def fields(self) -> tuple[str, ...]:
        return self.dtype.names

    def offset(self, field: str) -> int:
        """Byte offset of a field (the runtime-sized tail's too)."""
        if self.tail is not None and field == self.tail[0]:
            return self.tail[1]
        return self.dtype.fields[field][1]

    def zeros(self, n: int | None = None, stride: int | None = None) -> np.ndarray:
        """Zeroed records: one (n None) or [n], `stride` bytes apart (default: the struct size;
        uniform slots use UNIFORM_STRIDE)."""
        dt = self.dtype
        if stride is not None and stride != dt.itemsize:
            if stride < dt.itemsize:
                raise ValueError(f"stride {stride} is smaller than struct {self.name} ({dt.itemsize} bytes)")
            dt = np.dtype({**_fields_of(dt), "itemsize": int(stride)})
        return np.zeros(() if n is None else int(n), dt)

    def pack(self, **values) -> np.ndarray:
        """One record as bytes (a uint8 array of `size`), unnamed fields zero."""
        rec = self.zeros(1)
        self.fill(rec, **values)
        return rec.view(np.uint8)

    def fill(self, records: np.ndarray, **values) -> np.ndarray:
        """Set fields by name (broadcast over records); an unknown name is an error, not a no-op."""
        for k, v in values.items():
            if k not in self.dtype.names:
                raise KeyError(f"struct {self.name} has no field {k!r} (fields: {', '.join(self.dtype.names)})")
            records[k] = v
        return records

    def __repr__(self) -> str:
        return f"Struct({self.name}, {self.size} bytes: {', '.join(self.dtype.names)})"


def _fields_of(dt: np.dtype) -> dict:
    names = list(dt.names)
    return {
        "names": names,
        "formats": [dt.fields[n][0] for n in names],
        "offsets": [dt.fields[n][1] for n in names],
    }


@functools.cache
def _shader_struct(shader: str, name: str, defines: tuple) -> Struct:
    return Struct.from_wgsl(shader_source(shader, dict(defines)), name)


@functools.cache
def _shader_constants(shader: str, defines: tuple, constants: tuple) -> dict:
    return wgsl_constants(shader_source(shader, dict(defines)), dict(constants))


@functools.cache
def _entry_bindings(shader: str, entry: str, defines: tuple) -> tuple[dict, dict]:
    src = shader_source(shader, dict(defines))
    return wgsl_bindings(src), entry_bindings(src, entry)


@functools.cache
def _entry_workgroup_size(shader: str, entry: str, defines: tuple, constants: tuple) -> tuple[int, int, int]:
    return workgroup_size(shader_source(shader, dict(defines)), entry, dict(constants))


def as_bytes(records: np.ndarray) -> np.ndarray:
    """The bytes of structured records (for queue writes)."""
    return np.ascontiguousarray(records).reshape(-1).view(np.uint8)


class Uniforms:
    """Slots of one Struct in one uniform buffer, UNIFORM_STRIDE bytes apart. `rows` is the host
    copy (fill it by field name), `write()` uploads it, `binding(i)` is slot i for Kernel.bind.
    Queue writes land before the whole next submission: a value that must differ between
    dispatches of one submission gets its own slot."""

    def __init__(self, gpu: GPU, struct: Struct, slots: int = 1, label: str = ""):
        self.gpu, self.struct = gpu, struct
        self.slots = max(1, int(slots))
        self.rows = struct.zeros(self.slots, stride=UNIFORM_STRIDE)
        self.buffer = gpu.buffer(UNIFORM_STRIDE * self.slots, UNIFORM, label or struct.name)

    def write(self):
        self.gpu.write(self.buffer, as_bytes(self.rows))

    def binding(self, slot: int = 0) -> tuple:
        return (self.buffer, int(slot) * UNIFORM_STRIDE, self.struct.size)


# ------------------------------------------------------------------------------------------------
# Kernel
# ------------------------------------------------------------------------------------------------
def _forget(kernel_ref, buffer_id: int):
    kernel = kernel_ref()
    if kernel is not None:
        kernel.forget(buffer_id)


class Kernel:
    """One compute entry point of shaders/SHADER.wgsl: its pipeline (from the GPU's cache), its
    bind groups (cached by what they bind) and its dispatches.

    `record(cpass, bindings, threads= | workgroups= | indirect=, **buffers)` records one dispatch
    into a caller's compute pass; `dispatch(encoder, ...)` wraps it in a pass of its own
    (tools/bench.py attributes GPU time by the pipeline's label, SHADER:ENTRY). Buffers are given
    by the names the shader declares (module docstring), as keywords, a {name: buffer} mapping
    `bindings`, or both: buffer | (buffer, offset, size). `threads`
    gives ceil(threads / workgroup x) workgroups, split into rows of MAX_GROUPS_X as
    gpu.device.dispatch_dims does (shaders read the id back with `linear_wg`); `workgroups` is
    a count (split likewise) or an (x, y, z) grid; `indirect` is (buffer, byte_offset).
    """

    def __init__(
        self,
        gpu: GPU,
        shader: str,
        entry: str = "main",
        *,
        constants: dict | None = None,
        defines: dict | None = None,
        label: str | None = None,
    ):
        self.gpu, self.shader, self.entry = gpu, shader, entry
        self.defines = dict(defines or {})
        self.constants = dict(constants or {})
        self.pipeline = gpu.pipeline(shader, entry, self.constants, self.defines)
        self.label = label or f"{shader}:{entry}"
        self.workgroup_size = _entry_workgroup_size(
            shader, entry, tuple(sorted(self.defines.items())), tuple(sorted(self.constants.items()))
        )
        # {name: (group, binding)}: every binding the shader declares, and those the entry uses
        self.declared, self.expects = _entry_bindings(shader, entry, tuple(sorted(self.defines.items())))
        clash = {"threads", "workgroups", "indirect"} & set(self.declared)
        if clash:
            raise ValueError(f"kernel {self.label}: binding names {sorted(clash)} clash with dispatch's arguments")
        self._bind_groups: dict[tuple, tuple] = {}  # key -> (bind group, ids of its buffers)
        # what a call gave, by name (buffer identities, ranges) -> ((group, bind group), ...), ids:
        # a repeated call skips resolving names (recording is on the frame's critical path)
        self._named: dict[tuple, tuple] = {}
        self._keys_of: dict[int, set] = {}  # id(buffer) -> keys (of either cache) that hold it

    def struct(self, name: str) -> Struct:
        """A struct of this kernel's shader source."""
        return Struct.from_shader(self.shader, name, self.defines)

    def const(self, name: str) -> int:
        """An integer `const` or `override` of this kernel's shader as its pipeline was compiled
        (the kernel's pipeline constants replace the overrides' defaults), by name: a host value
        that must equal the shader's (a mode, a flag), so the number lives in the shader alone."""
        values = _shader_constants(
            self.shader, tuple(sorted(self.defines.items())), tuple(sorted(self.constants.items()))
        )
        if name not in values:
            raise KeyError(f"kernel {self.label}'s shader declares no integer const {name!r}")
        return values[name]

    # ---- bind groups ---------------------------------------------------------------------------
    def resolve(self, bindings=None, **buffers) -> dict[int, dict]:
        """{group: {binding: resource}} of buffers given by name (a mapping, keywords or both):
        an undeclared or non-string name, or a name the entry point uses and the call leaves out,
        is an error naming this kernel and the names it expects; declared names the entry point
        does not use are passed over."""
        given = {**bindings, **buffers} if bindings else buffers
        groups: dict[int, dict] = {}
        for name, res in given.items():
            at = self.expects.get(name)
            if at is None:
                if name in self.declared:
                    continue
                raise KeyError(f"kernel {self.label} has no binding {name!r} (it expects: {', '.join(self.expects)})")
            groups.setdefault(at[0], {})[at[1]] = res
        if sum(len(g) for g in groups.values()) != len(self.expects):
            missing = [n for n in self.expects if n not in given]
            raise KeyError(
                f"kernel {self.label} is missing binding(s) {', '.join(missing)} "
                f"(it expects: {', '.join(self.expects)})"
            )
        return groups

    def bind(self, bindings=None, **buffers) -> tuple:
        """The bind groups (group 0 first) of buffers given by name (`resolve`), each made once."""
        return tuple(bg for _, bg in self._bound(bindings, buffers))

    def _bound(self, bindings, buffers) -> tuple:
        """((group, bind group), ...) of a call's buffers by name, looked up by what it gave."""
        given = ({**bindings, **buffers} if buffers else bindings) if bindings else buffers
        key = tuple([(n, id(r[0]), r[1], r[2]) if r.__class__ is tuple else (n, id(r)) for n, r in given.items()])
        hit = self._named.get(key)
        if hit is not None:
            return hit[0]
        groups = self.resolve(given)
        bound = tuple((group, self._bind_group(res, group)) for group, res in sorted(groups.items()))
        self._remember(self._named, key, bound, given.values())
        return bound

    def _remember(self, cache: dict, key: tuple, value, resources):
        """cache[key] = value until one of the buffers of `resources` is collected."""
        ids = set()
        for r in resources:
            buf = r[0] if type(r) is tuple else r
            bid = id(buf)
            ids.add(bid)
            if bid not in self._keys_of:
                self._keys_of[bid] = set()
                weakref.finalize(buf, _forget, weakref.ref(self), bid).atexit = False
            self._keys_of[bid].add(key)
        cache[key] = (value, ids)

    def _bind_group(self, resources: dict, group: int):
        """The bind group of `resources` ({binding number: buffer | (buffer, offset, size)})."""
        key = (
            group,
            *[(b, id(r[0]), r[1], r[2]) if r.__class__ is tuple else (b, id(r)) for b, r in sorted(resources.items())],
        )
        hit = self._bind_groups.get(key)
        if hit is not None:
            return hit[0]
        bg = self.gpu.bind(self.pipeline, resources, group)
        self._remember(self._bind_groups, key, bg, resources.values())
        return bg

    def forget(self, buffer_id: int):
        """Drop the bind groups that bind a buffer (called when the buffer is collected)."""
        for key in self._keys_of.pop(buffer_id, ()):
            hit = self._bind_groups.pop(key, None) or self._named.pop(key, None)
            if hit is not None:
                for other in hit[1]:
                    if other != buffer_id and other in self._keys_of:
                        self._keys_of[other].discard(key)

    @property
    def cached_bind_groups(self) -> int:
        return len(self._bind_groups)

    # ---- dispatch ------------------------------------------------------------------------------
    def grid(self, threads: int) -> tuple[int, int, int]:
        """Workgroups for `threads` invocations along x (at least one workgroup)."""
        return dispatch_dims(-(-int(threads) // self.workgroup_size[0]))

    def record(self, cpass, bindings=None, /, *, threads=None, workgroups=None, indirect=None, **buffers):
        """Record one dispatch into the compute pass `cpass` (see the class docstring)."""
        if indirect is None:
            if threads is not None:
                grid = self.grid(threads)
            elif isinstance(workgroups, tuple):
                grid = workgroups
            elif workgroups is not None:
                grid = dispatch_dims(workgroups)
            else:
                raise ValueError(f"{self.label}: give threads, workgroups or indirect")
        bound = self._bound(bindings, buffers)
        cpass.set_pipeline(self.pipeline)
        for group, bg in bound:
            cpass.set_bind_group(group, bg)
        if indirect is None:
            cpass.dispatch_workgroups(*grid)
        else:
            cpass.dispatch_workgroups_indirect(indirect[0], int(indirect[1]))

    def dispatch(self, encoder, bindings=None, /, *, threads=None, workgroups=None, indirect=None, **buffers):
        """Record one dispatch in a compute pass of its own (unlabelled: a label costs ~3 us of
        encoding per pass; the pipeline's label names the pass)."""
        cpass = encoder.begin_compute_pass()
        self.record(cpass, bindings, threads=threads, workgroups=workgroups, indirect=indirect, **buffers)
        cpass.end()

    def __repr__(self) -> str:
        return f"Kernel({self.label}, workgroup {self.workgroup_size})"
