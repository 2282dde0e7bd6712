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

Reading: binary little- or big-endian, or ASCII; UTF-8 `comment` lines are fine. Properties are
looked up by name, never by position, because exporters differ: some sort the names as strings
(`f_rest_10` before `f_rest_2`), omit `nx ny nz`, add `comment` / `obj_info` lines, or carry
extra properties (colours, filter sizes, ...), which are ignored (mip-splatting's `filter_3D` with a
warning: its 3D filter is not applied). Required properties stored in
another numeric type (some tools write `double`) are converted to float32 (doubles round to
nearest, beyond the float32 range to +-Inf; integers convert exactly up to 2**24). ASCII values
are parsed as float64 (correctly rounded) and then rounded to the property's type. The header
parser and the ASCII reader are our own because plyfile decodes headers as ASCII and rejects
UTF-8 comments; plyfile still reads the rare binary file whose vertex element follows an element
with list properties. The decoding is vectorised over primitives, so multi-million-primitive
scenes load in a few seconds.

Every malformed input raises `PlyError` (a `ValueError`) whose message names the file and the
problem: not a PLY, an unknown format, no `vertex` element, missing required properties, an
`f_rest` count other than 0, 9, 24 or 45, gaps in the `f_rest` indices, zero primitives, or data
shorter than the header promises.
"""

from __future__ import annotations

import os
import re
import warnings

import numpy as np

from seuwgpu.model.fields import Model, sh_rest_count
from seuwgpu.model.formats.base import UP_AXES, ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError

__all__ = [
    "FORMAT",
    "PlyError",
    "PlyHeader",
    "load_ply",
    "save_ply",
    "read_header",
    "read_element",
    "model_from_header",
    "REQUIRED_PROPERTIES",
    "inria_property_names",
]


class PlyError(ModelFileError):
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


def save_ply(model: Model, path, comments=()) -> None:
    """Write `model` as an INRIA 3DGS PLY (binary little-endian float32, INRIA property order).

    Normals (nx, ny, nz) are written as zero. The values are copied bit for bit. `comments` become
    `comment` lines (seuwgpu records the up axis as `comment up +z`).
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
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments), f"element vertex {n}"]
    header += [f"property float {name}" for name in names]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("utf-8"))
        f.write(memoryview(np.ascontiguousarray(out)).cast("B"))


# -------------------------------------------------------------------------------------- loading


class PlyElement:
    """One element of a PLY header: its name, row count and (name, numpy type) properties."""

    def __init__(self, name: str, count: int):
        self.name, self.count = name, count
        self.props: list[tuple[str, str]] = []  # (name, numpy type) for scalars, (name, "list") for lists
        self.list_types: dict[str, tuple[str, str]] = {}  # list property -> (count type, item type)

    @property
    def has_list(self) -> bool:
        return bool(self.list_types)

    def names(self) -> list[str]:
        return [name for name, _ in self.props]

    def dtype(self, byteorder: str = "<") -> np.dtype:
        return np.dtype([(name, np.dtype(t).newbyteorder(byteorder)) for name, t in self.props])


class PlyHeader:
    """A parsed PLY header: format, elements, comments and where the data starts."""

    def __init__(self, path: str, fmt: str, elements: list[PlyElement], comments: list[str], data_start: int):
        self.path, self.format, self.elements, self.comments, self.data_start = (
            path,
            fmt,
            elements,
            comments,
            data_start,
        )

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)

    @property
    def byteorder(self) -> str:
        return ">" if self.format == "binary_big_endian" else "<"


_FORMATS = ("binary_little_endian", "binary_big_endian", "ascii")


def read_header(path) -> PlyHeader:
    """Parse a PLY header (UTF-8 comments allowed). Raises PlyError naming the file."""
    spath = os.fspath(path)
    with open(spath, "rb") as f:
        head = f.read(4096)
        if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
            raise PlyError(f"{spath}: not a PLY file (it does not start with the 'ply' magic line)")
        end = re.compile(rb"(?:\A|\n)end_header[ \t]*\r?\n")
        m = end.search(head)
        while m is None:
            more = f.read(max(len(head), 1 << 16))
            if not more or len(head) > _MAX_HEADER:
                raise PlyError(f"{spath}: PLY header has no 'end_header' line (truncated or corrupt header)")
            head += more
            m = end.search(head)
    data_start = m.end()
    try:
        text = head[:data_start].decode("utf-8")
    except UnicodeDecodeError:
        raise PlyError(f"{spath}: PLY header is neither ASCII nor UTF-8 (corrupt header)") from None

    fmt = None
    elements: list[PlyElement] = []
    comments: list[str] = []
    for lineno, raw in enumerate(text.splitlines()[1:], start=2):
        words = raw.split()
        if not words:
            continue
        key = words[0]
        if key in ("comment", "obj_info"):
            comments.append(raw.strip()[len(key) :].strip())
            continue
        if not raw.isascii():
            raise PlyError(f"{spath}: non-ASCII characters outside a comment in header line {lineno}: {raw!r}")
        if key == "end_header":
            break
        if key == "format":
            if len(words) != 3:
                raise PlyError(f"{spath}: malformed format line {raw!r} (header line {lineno})")
            if words[2] not in ("1.0", "1"):  # the only PLY version there is; another is no PLY we know
                raise PlyError(f"{spath}: PLY version {words[2]!r} in {raw!r}; only 1.0 exists (header line {lineno})")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{spath}: malformed element line {raw!r} (header line {lineno})")
            elements.append(PlyElement(words[1], int(words[2])))
        elif key == "property":
            if not elements:
                raise PlyError(f"{spath}: property before any element (header line {lineno})")
            el = elements[-1]
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    raise PlyError(f"{spath}: unknown PLY type in {raw!r} (header line {lineno})")
                el.list_types[words[4]] = (_PLY_TYPES[words[2]], _PLY_TYPES[words[3]])
                el.props.append((words[4], "list"))
            elif len(words) == 3:
                if words[1] not in _PLY_TYPES:
                    raise PlyError(
                        f"{spath}: unknown PLY type {words[1]!r} in {raw!r} "
                        f"(header line {lineno}); valid types: {', '.join(_PLY_TYPES)}"
                    )
                el.props.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise PlyError(f"{spath}: malformed property line {raw!r} (header line {lineno})")
        else:
            raise PlyError(f"{spath}: unexpected header line {raw!r} (header line {lineno})")
    if fmt is None:
        raise PlyError(f"{spath}: PLY header has no 'format' line")
    if fmt not in _FORMATS:
        raise PlyError(f"{spath}: unknown PLY format {fmt!r}; expected one of {', '.join(_FORMATS)}")
    return PlyHeader(spath, fmt, elements, comments, data_start)


def read_element(header: PlyHeader, name: str) -> np.ndarray:
    """The rows of element `name` as a structured array in native byte order (scalar properties
    only; an element with list properties raises PlyError). Binary data is read with numpy; ASCII
    data is parsed here (plyfile rejects UTF-8 header comments)."""
    path = header.path
    index = next((i for i, e in enumerate(header.elements) if e.name == name), None)
    if index is None:
        found = ", ".join(e.name for e in header.elements) or "none"
        raise PlyError(f"{path}: PLY has no {name!r} element (elements found: {found})")
    el = header.elements[index]
    if el.has_list:
        raise PlyError(
            f"{path}: the {name} element has list properties ({', '.join(el.list_types)}), which a 3DGS PLY never has"
        )
    if header.format == "ascii":
        return _read_ascii_element(header, index)
    return _read_binary_element(header, index)


def _read_binary_element(header: PlyHeader, index: int) -> np.ndarray:
    path, el, order = header.path, header.elements[index], header.byteorder
    dtype = el.dtype(order)
    with open(path, "rb") as f:
        file_size = os.fstat(f.fileno()).st_size
        if any(e.has_list for e in header.elements[:index]):
            if order != "<":
                raise PlyError(f"{path}: big-endian PLY with list elements before {el.name!r} is not supported")
            rows, end = _element_via_plyfile(path, el.name)
            if index == len(header.elements) - 1 and file_size - end >= dtype.itemsize:
                _too_many_rows(path, el.name, el.count, (file_size - end) // dtype.itemsize + el.count)
            return rows
        offset = header.data_start + sum(e.count * e.dtype().itemsize for e in header.elements[:index])
        n = el.count
        need = offset + n * dtype.itemsize
        if file_size < need:
            have = max(0, file_size - offset)
            noun = _rows_noun(el.name)
            raise PlyError(
                f"{path}: truncated PLY: the header promises {n} {noun} of "
                f"{dtype.itemsize} bytes ({n * dtype.itemsize} bytes of {el.name} data) but only "
                f"{have} bytes follow ({have // max(dtype.itemsize, 1)} whole {noun}); "
                f"file is {file_size} bytes, expected at least {need}"
            )
        if index == len(header.elements) - 1 and file_size - need >= dtype.itemsize:
            # whole rows beyond the header's count: the count is wrong (a tool that appended
            # splats, an edited header), and reading only `n` would drop the rest silently.
            # (Less than one row of trailing bytes is tolerated, as other readers do.)
            _too_many_rows(path, el.name, n, (file_size - offset) // dtype.itemsize)
        f.seek(offset)
        raw = np.fromfile(f, dtype=dtype, count=n)
    if raw.shape[0] != n:  # file shrank while reading
        raise PlyError(f"{path}: truncated PLY: read {raw.shape[0]} of {n} {el.name} rows")
    return raw.astype(raw.dtype.newbyteorder("="), copy=False) if order == ">" else raw


def _read_ascii_element(header: PlyHeader, index: int) -> np.ndarray:
    """ASCII rows are one line each; rows of earlier elements (lists included) are skipped by line."""
    path, el = header.path, header.elements[index]
    with open(path, "rb") as f:
        f.seek(header.data_start)
        text = f.read().decode("ascii", errors="replace")
    lines = text.splitlines()
    first = sum(e.count for e in header.elements[:index])
    rows = [ln for ln in lines[first : first + el.count]]
    names = el.names()
    for i, ln in enumerate(rows):  # name the first row that is not one whole row (before counting)
        held = len(ln.split())
        if held != len(names) and (held or i + 1 < len(rows) or first + el.count < len(lines)):
            what = "is blank" if not held else f"holds {held} values, expected {len(names)}"
            raise PlyError(
                f"{path}: ASCII PLY {el.name} row {i + 1} (data line {first + i + 1}) {what}: each row is "
                "one line, with no blank lines between rows"
            )
    beyond = sum(1 for ln in lines[first + el.count :] if ln.strip())
    if index == len(header.elements) - 1 and beyond:
        _too_many_rows(path, el.name, el.count, el.count + beyond)
    if len(rows) < el.count or any(not ln.strip() for ln in rows):
        got = sum(1 for ln in rows if ln.strip())
        raise PlyError(f"{path}: truncated ASCII PLY: the header promises {el.count} {el.name} rows, found {got}")
    # every row now holds one value per property (checked above): the table is whole
    tokens = " ".join(rows).split()
    out = np.empty(el.count, dtype=el.dtype("="))
    try:
        table = np.asarray(tokens).reshape(el.count, len(names))
        for j, (pname, t) in enumerate(el.props):
            # decimal -> float64 (correctly rounded) -> the property's type (float32 rounds once more)
            out[pname] = table[:, j].astype(np.float64 if np.dtype(t).kind == "f" else np.int64)
    except ValueError as e:
        raise PlyError(f"{path}: ASCII PLY {el.name} data is not numeric ({e})") from None
    return out


def _rows_noun(name: str) -> str:
    return "vertices" if name == "vertex" else f"{name} rows"


def _too_many_rows(path: str, name: str, declared: int, held: int):
    """Refuse whole rows beyond the header's count (binary or ASCII): reading only the declared
    ones would drop the rest silently."""
    raise PlyError(
        f"{path}: the header declares {declared} {_rows_noun(name)} but the data holds {held}: "
        "fix the header's element count"
    )


def _element_via_plyfile(path: str, name: str) -> tuple[np.ndarray, int]:
    """The element's rows, read by plyfile, and the byte offset where the file's data ended."""
    import plyfile

    try:
        with open(path, "rb") as f:
            data = plyfile.PlyData.read(f)
            rows = np.asarray(data[name].data)
            return rows, f.tell()
    except Exception as e:  # plyfile's own parse errors
        raise PlyError(f"{path}: could not read the {name} data: {e}") from e


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

    Binary little- or big-endian, or ASCII. Required vertex properties: x y z f_dc_0..2 opacity
    scale_0..2 rot_0..3 and f_rest_0..K-1 with K in (0, 9, 24, 45). Any other property (normals,
    colours, ...) is ignored. Properties stored as double (or another numeric type) are converted
    to float32, doubles rounding to nearest (+-Inf beyond the float32 range); float32 properties
    are kept bit for bit. Raises PlyError on malformed input.
    """
    header = read_header(path)
    return model_from_header(header)


def model_from_header(header: PlyHeader) -> Model:
    """The INRIA model held by the `vertex` element of a parsed PLY."""
    spath = header.path
    vert = header.element("vertex")
    if vert is None:
        found = ", ".join(e.name for e in header.elements) or "none"
        raise PlyError(f"{spath}: PLY has no 'vertex' element (elements found: {found})")
    names = vert.names()
    dups = sorted({x for x in names if names.count(x) > 1})
    if dups:
        raise PlyError(f"{spath}: vertex properties are declared more than once: {', '.join(dups)}")
    missing = [p for p in REQUIRED_PROPERTIES if p not in names]
    if missing:
        raise PlyError(f"{spath}: vertex element lacks required 3DGS properties: {', '.join(missing)}")
    rest = _rest_columns(spath, names)
    if vert.count == 0:
        raise PlyError(f"{spath}: PLY holds zero primitives (element vertex 0)")
    if "filter_3D" in names:  # mip-splatting's output: its 3D smoothing filter is not applied here
        warnings.warn(f"{spath}: property filter_3D ignored: the model renders without mip-splatting's 3D filter")
    return _model_from_vertices(read_element(header, "vertex"), rest)


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


# ---------------------------------------------------------------------------------- the format


def is_ply(probe: Probe) -> bool:
    return probe.head.startswith((b"ply\n", b"ply\r\n"))


def recorded_up(path) -> str | None:
    """The up axis a PLY records in a `comment up AXIS` line (save_model writes one), or None."""
    for c in read_header(path).comments:
        words = c.split()
        if len(words) == 2 and words[0] == "up" and words[1] in UP_AXES:
            return words[1]
    return None


def _read(path: str) -> tuple[Model, list[str]]:
    header = read_header(path)
    notes = [] if header.format == "binary_little_endian" else [header.format.replace("_", " ")]
    return model_from_header(header), notes


def _write(model: Model, path: str, up: str | None = None, **_spz_options) -> None:
    """SPZ's options (version, antialiased) have no place in a PLY: ignored, so one call can write either."""
    save_ply(model, path, comments=[f"up {up}"] if up else ())


FORMAT = ModelFormat(
    name="ply",
    title="INRIA 3DGS PLY",
    suffixes=(".ply",),
    up="-y",
    sniff=is_ply,
    read=_read,
    write=_write,
    recorded_up=recorded_up,
    exact=True,
)
