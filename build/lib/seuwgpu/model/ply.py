"""INRIA 3DGS PLY files: `load_ply(path) -> Model` and `save_ply(model, path)`.

The format (graphdeco-inria/gaussian-splatting, `GaussianModel.save_ply`) is one `vertex` element,
binary little-endian float32, with the properties

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3R-1}  opacity
    scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

`scale_*` are log-scales, `opacity` is the logit, `rot_*` is the quaternion (w, x, y, z) and
`f_dc_*` is the SH DC term. `f_rest` is channel-major in the file (R coefficients per channel:
all red, then all green, then all blue), while `Model.sh_rest` is coefficient-major:

    model.sh_rest[i, k, c] == f_rest_{c*R + k}[i]

Writing: exactly the INRIA property order above (normals written as zero), so that the files
open in other 3DGS tools (SuperSplat, gsplat, the INRIA viewer). Values are copied bit for bit,
NaN payloads and -0.0 included.

Reading: properties are looked up by name, never by position, because exporters differ: some
sort the names as strings (`f_rest_10` before `f_rest_2`), omit `nx ny nz`, add `comment` /
`obj_info` lines, or carry extra properties (colours, filter sizes, ...), which are ignored.
Required properties stored in another numeric type (some tools write `double`) are converted to
float32 (doubles round to nearest, beyond the float32 range to +-Inf; integers convert exactly
up to 2**24). The decoding is
vectorised over primitives, so multi-million-primitive scenes load in a few seconds.

Every malformed input raises `PlyError` (a `ValueError`) whose message names the file and the
problem: not a PLY, ASCII or big-endian encoding, no `vertex` element, missing required
properties, an `f_rest` count other than 0, 9, 24 or 45, gaps in the `f_rest` indices, zero
primitives, or data shorter than the header promises.
"""

from __future__ import annotations

import os
import re

import numpy as np

from seuwgpu.model.fields import Model, sh_rest_count

__all__ = ["PlyError", "load_ply", "save_ply", "REQUIRED_PROPERTIES", "inria_property_names"]


class PlyError(ValueError):
    """A PLY file that cannot be read as a 3DGS model (the message names file and problem)."""


# PLY scalar type names (both spellings of the spec) -> little-endian numpy type.
_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "<i2",
    "int16": "<i2",
    "ushort": "<u2",
    "uint16": "<u2",
    "int": "<i4",
    "int32": "<i4",
    "uint": "<u4",
    "uint32": "<u4",
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
}

# Required properties other than f_rest_*, grouped by model field (file order within a field).
_FIELD_PROPS = {
    "means": ("x", "y", "z"),
    "sh_dc": ("f_dc_0", "f_dc_1", "f_dc_2"),
    "opacity": ("opacity",),
    "log_scales": ("scale_0", "scale_1", "scale_2"),
    "quats": ("rot_0", "rot_1", "rot_2", "rot_3"),
}
REQUIRED_PROPERTIES = (
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
)
_VALID_REST = {3 * sh_rest_count(d): d for d in range(4)}  # {0: 0, 9: 1, 24: 2, 45: 3}
_F_REST = re.compile(r"f_rest_(.*)\Z")
_MAX_HEADER = 64 << 20  # give up looking for end_header after this many bytes


def inria_property_names(degree: int) -> list[str]:
    """The vertex property names, in the order the INRIA code writes them, for an SH degree."""
    nrest = 3 * sh_rest_count(degree)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{j}" for j in range(nrest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


# --------------------------------------------------------------------------------------- saving


def save_ply(model: Model, path) -> None:
    """Write `model` as an INRIA 3DGS PLY (binary little-endian float32, INRIA property order).

    Normals (nx, ny, nz) are written as zero. The values are copied bit for bit.
    """
    if not isinstance(model, Model):
        raise TypeError(f"save_ply expects a Model, got {type(model).__name__}")
    n = model.n
    if n == 0:
        raise PlyError(
            f"{os.fspath(path)}: refusing to write a model with zero primitives (load_ply rejects such files)"
        )
    r = model.sh_rest.shape[1]
    names = inria_property_names(model.sh_degree)
    out = np.empty((n, len(names)), dtype="<f4")
    out[:, 0:3] = model.means
    out[:, 3:6] = 0.0
    out[:, 6:9] = model.sh_dc
    # coefficient-major [N, R, 3] -> channel-major [N, 3, R] -> f_rest_{c*R + k}
    out[:, 9 : 9 + 3 * r] = model.sh_rest.transpose(0, 2, 1).reshape(n, 3 * r)
    j = 9 + 3 * r
    out[:, j] = model.opacity
    out[:, j + 1 : j + 4] = model.log_scales
    out[:, j + 4 : j + 8] = model.quats
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name in names]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(memoryview(np.ascontiguousarray(out)).cast("B"))


# -------------------------------------------------------------------------------------- loading


class _Element:
    def __init__(self, name: str, count: int):
        self.name, self.count = name, count
        self.props: list[tuple[str, str]] = []  # (name, numpy type) for scalar properties
        self.has_list = False

    def dtype(self) -> np.dtype:
        return np.dtype([(name, t) for name, t in self.props])


def _read_header(path: str, f) -> tuple[list[_Element], int, str]:
    """Parse the header; returns (elements, data offset, format name)."""
    head = f.read(4096)
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise PlyError(f"{path}: not a PLY file (it does not start with the 'ply' magic line)")
    end = re.compile(rb"(?:\A|\n)end_header[ \t]*\r?\n")
    m = end.search(head)
    while m is None:
        more = f.read(max(len(head), 1 << 16))
        if not more or len(head) > _MAX_HEADER:
            raise PlyError(f"{path}: PLY header has no 'end_header' line (truncated or corrupt header)")
        head += more
        m = end.search(head)
    data_start = m.end()
    try:
        text = head[:data_start].decode("ascii")
    except UnicodeDecodeError:
        raise PlyError(f"{path}: PLY header contains non-ASCII bytes (corrupt header)") from None

    fmt = None
    elements: list[_Element] = []
    for lineno, raw in enumerate(text.splitlines()[1:], start=2):
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if len(words) != 3:
                raise PlyError(f"{path}: malformed format line {raw!r} (header line {lineno})")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{path}: malformed element line {raw!r} (header line {lineno})")
            elements.append(_Element(words[1], int(words[2])))
        elif key == "property":
            if not elements:
                raise PlyError(f"{path}: property before any element (header line {lineno})")
            el = elements[-1]
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    raise PlyError(f"{path}: unknown PLY type in {raw!r} (header line {lineno})")
                el.has_list = True
                el.props.append((words[4], "list"))
            elif len(words) == 3:
                if words[1] not in _PLY_TYPES:
                    raise PlyError(
                        f"{path}: unknown PLY type {words[1]!r} in {raw!r} "
                        f"(header line {lineno}); valid types: {', '.join(_PLY_TYPES)}"
                    )
                el.props.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise PlyError(f"{path}: malformed property line {raw!r} (header line {lineno})")
        else:
            raise PlyError(f"{path}: unexpected header line {raw!r} (header line {lineno})")
    if fmt is None:
        raise PlyError(f"{path}: PLY header has no 'format' line")
    if fmt == "ascii":
        raise PlyError(
            f"{path}: ASCII PLY is not supported; 3DGS models must be "
            "binary_little_endian (re-export the file as binary little-endian)"
        )
    if fmt == "binary_big_endian":
        raise PlyError(
            f"{path}: big-endian PLY (binary_big_endian) is not supported; 3DGS models must be binary_little_endian"
        )
    if fmt != "binary_little_endian":
        raise PlyError(f"{path}: unknown PLY format {fmt!r}; expected binary_little_endian")
    return elements, data_start, fmt


def _rest_columns(path: str, names: list[str]) -> list[str]:
    """f_rest property names ordered by index 0..K-1, after checking count and gaps."""
    idx: dict[int, str] = {}
    for name in names:
        m = _F_REST.match(name)
        if m is None:
            continue
        s = m.group(1)
        if not s.isdigit() or (len(s) > 1 and s[0] == "0"):
            raise PlyError(f"{path}: malformed SH property name {name!r} (expected f_rest_<index>)")
        idx[int(s)] = name
    k = len(idx)
    if k not in _VALID_REST:
        raise PlyError(
            f"{path}: the vertex element has {k} f_rest_* properties, which is no SH "
            "degree; valid counts are 0 (degree 0), 9 (degree 1), 24 (degree 2) "
            "or 45 (degree 3)"
        )
    missing = sorted(set(range(k)) - idx.keys())
    if missing:
        extra = sorted(set(idx) - set(range(k)))
        raise PlyError(
            f"{path}: f_rest indices have gaps: {k} f_rest_* properties but "
            f"f_rest_{missing[0]} is missing (missing {missing}, unexpected {extra}); "
            f"expected f_rest_0..f_rest_{k - 1}"
        )
    return [idx[j] for j in range(k)]


def load_ply(path) -> Model:
    """Read an INRIA 3DGS PLY into a Model (properties found by name; see the module docstring).

    Required vertex properties: x y z f_dc_0..2 opacity scale_0..2 rot_0..3 and f_rest_0..K-1
    with K in (0, 9, 24, 45). Any other property (normals, colours, ...) is ignored. Properties
    stored as double (or another numeric type) are converted to float32, doubles rounding to
    nearest (+-Inf beyond the float32 range); float32 properties are kept bit for bit.
    Raises PlyError on malformed input.
    """
    spath = os.fspath(path)
    with open(spath, "rb") as f:
        elements, data_start, _ = _read_header(spath, f)
        file_size = os.fstat(f.fileno()).st_size

        vi = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
        if vi is None:
            found = ", ".join(e.name for e in elements) or "none"
            raise PlyError(f"{spath}: PLY has no 'vertex' element (elements found: {found})")
        vert = elements[vi]
        names = [name for name, _ in vert.props]
        dups = sorted({x for x in names if names.count(x) > 1})
        if dups:
            raise PlyError(f"{spath}: vertex properties are declared more than once: {', '.join(dups)}")
        missing = [p for p in REQUIRED_PROPERTIES if p not in names]
        if missing:
            raise PlyError(f"{spath}: vertex element lacks required 3DGS properties: {', '.join(missing)}")
        rest = _rest_columns(spath, names)
        if vert.has_list:
            lists = [name for name, t in vert.props if t == "list"]
            raise PlyError(
                f"{spath}: vertex element has list properties ({', '.join(lists)}), which a 3DGS PLY never has"
            )
        n = vert.count
        if n == 0:
            raise PlyError(f"{spath}: PLY holds zero primitives (element vertex 0)")

        if any(e.has_list for e in elements[:vi]):
            raw = _vertex_via_plyfile(spath)  # rare: list data before the vertices
        else:
            offset = data_start + sum(e.count * e.dtype().itemsize for e in elements[:vi])
            vdtype = vert.dtype()
            need = offset + n * vdtype.itemsize
            if file_size < need:
                have = max(0, file_size - offset)
                raise PlyError(
                    f"{spath}: truncated PLY: the header promises {n} vertices of "
                    f"{vdtype.itemsize} bytes ({n * vdtype.itemsize} bytes of vertex data) but only "
                    f"{have} bytes follow ({have // vdtype.itemsize} whole vertices); "
                    f"file is {file_size} bytes, expected at least {need}"
                )
            f.seek(offset)
            raw = np.fromfile(f, dtype=vdtype, count=n)
            if raw.shape[0] != n:  # file shrank while reading
                raise PlyError(f"{spath}: truncated PLY: read {raw.shape[0]} of {n} vertices")

    return _model_from_vertices(raw, rest)


def _vertex_via_plyfile(path: str) -> np.ndarray:
    import plyfile

    try:
        data = plyfile.PlyData.read(path)
        return np.asarray(data["vertex"].data)
    except Exception as e:  # plyfile's own parse errors
        raise PlyError(f"{path}: could not read the vertex data: {e}") from e


def _model_from_vertices(raw: np.ndarray, rest: list[str]) -> Model:
    n = raw.shape[0]
    fields = raw.dtype.names
    r = len(rest) // 3
    # f_rest columns in coefficient-major order: (k, c) -> f_rest_{c*R + k}
    rest_cm = [rest[c * r + k] for k in range(r) for c in range(3)]
    groups = dict(_FIELD_PROPS, sh_rest=tuple(rest_cm))

    all_f32 = all(raw.dtype[name] == np.dtype("<f4") for name in fields)
    if all_f32:
        # One [N, P] float32 view; gathering columns is a single vectorised copy per field.
        flat = np.ascontiguousarray(raw).view("<f4").reshape(n, len(fields))
        col = {name: i for i, name in enumerate(fields)}

        def take(props):
            # np.take returns C-contiguous rows (fancy indexing flat[:, idx] would not).
            return np.take(flat, np.array([col[p] for p in props], dtype=np.intp), axis=1)
    else:

        def take(props):
            out = np.empty((n, len(props)), dtype=np.float32)
            with np.errstate(over="ignore"):  # doubles beyond the float32 range become +-Inf
                for j, p in enumerate(props):
                    out[:, j] = raw[p]  # double -> float32 rounds to nearest; floats copy exactly
            return out

    parts = {name: take(props) for name, props in groups.items()}
    return Model(
        means=parts["means"],
        log_scales=parts["log_scales"],
        quats=parts["quats"],
        opacity=parts["opacity"][:, 0],
        sh_dc=parts["sh_dc"],
        sh_rest=parts["sh_rest"].reshape(n, r, 3),
    )
