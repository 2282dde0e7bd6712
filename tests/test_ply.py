"""INRIA 3DGS PLY I/O: bit-exact round trips, tolerant loading by property name, and errors.

Reference files are built here byte by byte (numpy structured arrays + a header string), never
with save_ply, so the loader is checked against the format itself.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.ply import PlyError, load_ply, save_ply

TYPE_NAME = {
    "<f4": "float",
    ">f4": "float",
    "<f8": "double",
    "u1": "uchar",
    "<i4": "int",
    "i1": "char",
    "<u2": "ushort",
}

INRIA_DEG3 = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    + [f"f_rest_{j}" for j in range(45)]
    + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
)


# ----------------------------------------------------------------------------------- helpers


def write_raw_ply(
    path: Path,
    columns: list[tuple[str, str, np.ndarray]],
    *,
    fmt="binary_little_endian",
    header_extra=(),
    pre_elements=(),
    post_bytes=b"",
    count=None,
    newline="\n",
) -> Path:
    """Write a PLY by hand. columns: (name, numpy type, values[N]); pre_elements:
    (header lines, raw bytes) of elements placed before `vertex`."""
    n = len(columns[0][2]) if columns else 0
    dt = np.dtype([(name, t) for name, t, _ in columns])
    arr = np.zeros(n, dtype=dt)
    for name, _, vals in columns:
        arr[name] = vals
    lines = ["ply", f"format {fmt} 1.0", *header_extra]
    body = b""
    for hdr, raw in pre_elements:
        lines += hdr
        body += raw
    lines.append(f"element vertex {n if count is None else count}")
    lines += [f"property {TYPE_NAME[t]} {name}" for name, t, _ in columns]
    lines.append("end_header")
    path.write_bytes((newline.join(lines) + newline).encode("utf-8") + body + arr.tobytes() + post_bytes)
    return path


def inria_columns(model: Model, *, normals=True, dtype="<f4") -> list[tuple[str, str, np.ndarray]]:
    """Model -> INRIA property columns, written out independently of save_ply."""
    n, r = model.n, model.sh_rest.shape[1]
    cols = [("x", dtype, model.means[:, 0]), ("y", dtype, model.means[:, 1]), ("z", dtype, model.means[:, 2])]
    if normals:
        cols += [(f"n{a}", dtype, np.zeros(n)) for a in "xyz"]
    cols += [(f"f_dc_{c}", dtype, model.sh_dc[:, c]) for c in range(3)]
    for c in range(3):
        for k in range(r):
            cols.append((f"f_rest_{c * r + k}", dtype, model.sh_rest[:, k, c]))
    cols.append(("opacity", dtype, model.opacity))
    cols += [(f"scale_{a}", dtype, model.log_scales[:, a]) for a in range(3)]
    cols += [(f"rot_{a}", dtype, model.quats[:, a]) for a in range(4)]
    return cols


def random_model(n=7, degree=3, seed=0) -> Model:
    rng = np.random.default_rng(seed)
    r = (degree + 1) ** 2 - 1
    return Model(
        means=rng.standard_normal((n, 3)),
        log_scales=rng.standard_normal((n, 3)),
        quats=rng.standard_normal((n, 4)),
        opacity=rng.standard_normal(n),
        sh_dc=rng.standard_normal((n, 3)),
        sh_rest=rng.standard_normal((n, r, 3)),
    )


def assert_models_bit_equal(a: Model, b: Model):
    assert a.n == b.n and a.sh_degree == b.sh_degree
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.shape == y.shape, f
        np.testing.assert_array_equal(x.view(np.uint32), y.view(np.uint32), err_msg=f)


SPECIAL_BITS = np.array(
    [
        0x7F800001,  # signalling NaN, smallest payload
        0xFFC12345,  # negative quiet NaN with payload
        0x7FBFFFFF,  # signalling NaN, largest payload
        0x7F800000,
        0xFF800000,  # +-Inf
        0x80000000,  # -0.0
        0x00000001,
        0x807FFFFF,  # subnormals
        0x7F7FFFFF,  # float32 max
    ],
    dtype=np.uint32,
)


def special_model(degree: int, n=11) -> Model:
    m = random_model(n, degree, seed=degree)
    flat = m.flat()
    bits = flat.view(np.uint32)
    # scatter the special patterns over every component (cycling), row by row
    for i in range(n):
        bits[i, i % flat.shape[1] :: 5] = SPECIAL_BITS[i % len(SPECIAL_BITS)]
    return Model.from_flat(flat, degree)


# ------------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_bit_exact_with_special_values(tmp_path, degree):
    m = special_model(degree)
    assert np.isnan(m.flat()).any() and np.isinf(m.flat()).any()
    p = tmp_path / f"d{degree}.ply"
    save_ply(m, p)
    back = load_ply(p)
    assert back.sh_degree == degree
    assert_models_bit_equal(m, back)
    # str paths work too
    assert_models_bit_equal(m, load_ply(str(p)))


def test_saved_file_is_exactly_inria_layout(tmp_path):
    m = random_model(5, 3)
    p = tmp_path / "m.ply"
    save_ply(m, p)
    data = p.read_bytes()
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:header_end].decode("ascii").splitlines()
    assert header[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 5"]
    assert header[3:-1] == [f"property float {name}" for name in INRIA_DEG3]
    assert header[-1] == "end_header"
    assert len(data) - header_end == 5 * 62 * 4
    rows = np.frombuffer(data[header_end:], dtype="<f4").reshape(5, 62)
    np.testing.assert_array_equal(rows[:, 0:3], m.means)
    np.testing.assert_array_equal(rows[:, 3:6], 0.0)
    np.testing.assert_array_equal(rows[:, 6:9], m.sh_dc)
    for j in range(45):  # f_rest_j = channel j // 15, coefficient j % 15
        np.testing.assert_array_equal(rows[:, 9 + j], m.sh_rest[:, j % 15, j // 15])
    np.testing.assert_array_equal(rows[:, 54], m.opacity)
    np.testing.assert_array_equal(rows[:, 55:58], m.log_scales)
    np.testing.assert_array_equal(rows[:, 58:62], m.quats)


def test_saved_file_reads_in_plyfile(tmp_path):
    plyfile = pytest.importorskip("plyfile")
    m = random_model(4, 2)
    p = tmp_path / "m.ply"
    save_ply(m, p)
    v = plyfile.PlyData.read(str(p))["vertex"]
    assert [prop.name for prop in v.properties][9:12] == ["f_rest_0", "f_rest_1", "f_rest_2"]
    # degree 2: R = 8 coefficients per channel
    np.testing.assert_array_equal(v["f_rest_7"], m.sh_rest[:, 7, 0])  # red, last coefficient
    np.testing.assert_array_equal(v["f_rest_8"], m.sh_rest[:, 0, 1])  # green, first
    np.testing.assert_array_equal(v["f_rest_9"], m.sh_rest[:, 1, 1])  # green, second
    np.testing.assert_array_equal(v["f_rest_23"], m.sh_rest[:, 7, 2])  # blue, last
    np.testing.assert_array_equal(v["rot_0"], m.quats[:, 0])
    np.testing.assert_array_equal(v["nx"], 0.0)


def test_degree0_has_no_f_rest(tmp_path):
    m = random_model(3, 0)
    p = tmp_path / "m.ply"
    save_ply(m, p)
    assert b"f_rest" not in p.read_bytes()[:2000]
    assert load_ply(p).sh_rest.shape == (3, 0, 3)


def test_save_refuses_empty_model(tmp_path):
    empty = random_model(3, 1).subset(slice(0, 0))
    with pytest.raises(PlyError, match="zero primitives"):
        save_ply(empty, tmp_path / "e.ply")


# -------------------------------------------------------------------- channel-major mapping


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_channel_major_mapping_from_hand_built_file(tmp_path, degree):
    n, r = 4, (degree + 1) ** 2 - 1
    i = np.arange(n, dtype=np.float64)
    cols = [
        (name, "<f4", 1000 * i + v)
        for v, name in enumerate(
            [
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
            ]
        )
    ]
    # f_rest_j holds 100 + j (+ 1000 * primitive)
    cols += [(f"f_rest_{j}", "<f4", 1000 * i + 100 + j) for j in range(3 * r)]
    m = load_ply(write_raw_ply(tmp_path / "h.ply", cols))
    assert m.sh_degree == degree
    for prim in range(n):
        for k in range(r):
            for c in range(3):
                assert m.sh_rest[prim, k, c] == 1000 * prim + 100 + c * r + k
    np.testing.assert_array_equal(m.means[1], [1000, 1001, 1002])
    np.testing.assert_array_equal(m.sh_dc[2], [2003, 2004, 2005])
    np.testing.assert_array_equal(m.opacity, 1000 * i + 6)
    np.testing.assert_array_equal(m.log_scales[3], [3007, 3008, 3009])
    np.testing.assert_array_equal(m.quats[0], [10, 11, 12, 13])  # rot_0 is w


# ------------------------------------------------------------------ tolerant loading by name


@pytest.fixture
def ref():
    return special_model(3, n=9)


def test_loads_inria_file_written_by_hand(tmp_path, ref):
    assert_models_bit_equal(ref, load_ply(write_raw_ply(tmp_path / "a.ply", inria_columns(ref))))


def test_string_sorted_property_order(tmp_path, ref):
    cols = sorted(inria_columns(ref), key=lambda c: c[0])
    names = [c[0] for c in cols]
    assert names.index("f_rest_10") < names.index("f_rest_2")  # really string-sorted
    assert_models_bit_equal(ref, load_ply(write_raw_ply(tmp_path / "s.ply", cols)))


def test_shuffled_property_order(tmp_path, ref):
    cols = inria_columns(ref)
    order = np.random.default_rng(5).permutation(len(cols))
    assert_models_bit_equal(ref, load_ply(write_raw_ply(tmp_path / "r.ply", [cols[j] for j in order])))


def test_no_normals_comments_obj_info_and_extra_properties(tmp_path, ref):
    n = ref.n
    cols = inria_columns(ref, normals=False)
    cols.insert(3, ("red", "u1", np.arange(n) % 256))
    cols.insert(0, ("filter_3D", "<f4", np.full(n, 7.5)))
    cols.append(("tag", "<i4", np.arange(n) * -3))
    cols.append(("weight", "<f8", np.linspace(0, 1, n)))
    extra = [
        "comment generated by some exporter",
        "obj_info  anything goes here",
        "comment vertex 99 end_header lookalike",
    ]
    p = write_raw_ply(tmp_path / "e.ply", cols, header_extra=extra)
    with pytest.warns(UserWarning, match="filter_3D"):  # the one extra property not ignored silently
        assert_models_bit_equal(ref, load_ply(p))


def test_mip_splatting_filter_3d_warns_once(tmp_path, ref):
    """mip-splatting's filter_3D property is not applied: one warning names it (the model loads
    as without it), where it used to be dropped silently."""
    import warnings

    cols = inria_columns(ref)
    cols.append(("filter_3D", "<f4", np.full(ref.n, 0.01)))
    p = write_raw_ply(tmp_path / "mip.ply", cols)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = load_ply(p)
    assert_models_bit_equal(ref, got)
    assert len(caught) == 1
    assert "filter_3D" in str(caught[0].message) and "without mip-splatting's 3D filter" in str(caught[0].message)
    assert str(p) in str(caught[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an INRIA file without it: no warning
        load_ply(write_raw_ply(tmp_path / "plain.ply", inria_columns(ref)))


def test_long_header(tmp_path, ref):
    comments = [f"comment {'x' * 100} {i}" for i in range(2000)]  # ~200 KB of header
    assert_models_bit_equal(
        ref, load_ply(write_raw_ply(tmp_path / "long.ply", inria_columns(ref), header_extra=comments))
    )


def test_crlf_header(tmp_path, ref):
    p = write_raw_ply(tmp_path / "crlf.ply", inria_columns(ref), newline="\r\n")
    assert_models_bit_equal(ref, load_ply(p))


def test_double_typed_properties_convert_to_float32(tmp_path):
    m = random_model(6, 1)
    cols = inria_columns(m, dtype="<f8")  # float32 values are exact in double
    cols[0] = ("x", "<f8", np.array([0.1, 1 / 3, 1e-50, 1e300, -np.inf, np.nan]))
    cols[-1] = ("rot_3", "<f4", m.quats[:, 3])  # mixed float/double
    back = load_ply(write_raw_ply(tmp_path / "d.ply", cols))
    for f in FIELDS:
        if f != "means":
            np.testing.assert_array_equal(getattr(back, f), getattr(m, f), err_msg=f)
    np.testing.assert_array_equal(back.means[:, 1:], m.means[:, 1:])
    x = back.means[:, 0]
    assert x.dtype == np.float32
    assert x[0] == np.float32(0.1) and x[1] == np.float32(1 / 3)  # round to nearest
    assert x[2] == 0.0 and x[3] == np.inf and x[4] == -np.inf and np.isnan(x[5])


def test_other_elements_before_and_after_vertex(tmp_path, ref):
    cam = np.arange(6, dtype="<f4").tobytes()  # element camera: 2 rows of 3 floats
    pre = [(["element camera 2", "property float a", "property float b", "property float c"], cam)]
    p = write_raw_ply(
        tmp_path / "c.ply",
        inria_columns(ref),
        pre_elements=pre,
        post_bytes=b"\x03" + np.arange(3, dtype="<i4").tobytes(),
    )
    # the trailing face element is not declared; trailing bytes are simply ignored
    assert_models_bit_equal(ref, load_ply(p))


def test_list_element_before_vertex(tmp_path, ref):
    pytest.importorskip("plyfile")
    raw = b"\x02" + np.array([5, 6], "<i4").tobytes() + b"\x01" + np.array([7], "<i4").tobytes()
    pre = [(["element poly 2", "property list uchar int idx"], raw)]
    p = write_raw_ply(tmp_path / "l.ply", inria_columns(ref), pre_elements=pre)
    assert_models_bit_equal(ref, load_ply(p))
    # whole rows past the declared count are refused there too (they would be dropped silently)
    row = 4 * len(inria_columns(ref))
    with open(p, "ab") as f:
        f.write(bytes(2 * row + 3))
    expect_error(p, f"declares {ref.n} vertices but the data holds {ref.n + 2}")


# ----------------------------------------------------------------------------------- errors


def base_columns(n=3, rest=45):
    i = np.arange(n, dtype=np.float64)
    names = [
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
    ]
    names += [f"f_rest_{j}" for j in range(rest)]
    return [(name, "<f4", i) for name in names]


def expect_error(path, *fragments):
    with pytest.raises(PlyError) as e:
        load_ply(path)
    msg = str(e.value)
    assert str(path) in msg, msg
    for frag in fragments:
        assert re.search(frag, msg, re.IGNORECASE), (frag, msg)
    assert isinstance(e.value, ValueError)
    return msg


def test_error_not_a_ply(tmp_path):
    p = tmp_path / "x.ply"
    p.write_text("solid cube\nfacet normal 0 0 1\n")
    expect_error(p, "not a PLY")
    p.write_bytes(b"")
    expect_error(p, "not a PLY")
    p.write_bytes(np.random.default_rng(0).bytes(5000))
    expect_error(p, "not a PLY")
    p.write_bytes(b"plywood\n")
    expect_error(p, "not a PLY")


def test_error_unknown_ply_version(tmp_path, ref):
    """PLY has one version, 1.0: a header naming another is refused, not read as 1.0."""
    good = tmp_path / "ok.ply"
    save_ply(ref, good)
    data = good.read_bytes()
    bad = tmp_path / "v2.ply"
    bad.write_bytes(data.replace(b"binary_little_endian 1.0", b"binary_little_endian 2.0", 1))
    expect_error(bad, "PLY version '2.0'")


def test_error_header_without_end(tmp_path):
    p = tmp_path / "h.ply"
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n")
    expect_error(p, "end_header")


def test_big_endian_any_order(tmp_path, ref):
    cols = inria_columns(ref)
    cols = [(name, ">f4", vals) for name, _, vals in reversed(cols)]  # big-endian, reversed order
    p = write_raw_ply(tmp_path / "be.ply", cols, fmt="binary_big_endian", header_extra=["comment été ✓"])
    assert_models_bit_equal(ref, load_ply(p))


def _ascii_ply(path, names, rows, extra=()):
    head = ["ply", "format ascii 1.0", *extra, f"element vertex {len(rows)}"]
    head += [f"property float {name}" for name in names] + ["end_header"]
    path.write_text("\n".join(head) + "\n" + "".join(" ".join(r) + "\n" for r in rows), encoding="utf-8")
    return path


def test_ascii_with_utf8_comments_and_no_normals(tmp_path):
    m = random_model(5, 2, seed=4)
    cols = inria_columns(m, normals=False)
    rng = np.random.default_rng(1)
    cols = [cols[j] for j in rng.permutation(len(cols))]
    # shortest decimal that round-trips each float32 (what numpy and most exporters print)
    rows = [[np.format_float_positional(np.float32(c[2][i]), unique=True) for c in cols] for i in range(m.n)]
    p = _ascii_ply(tmp_path / "a.ply", [c[0] for c in cols], rows, ["comment créé avec ♥ par un exporteur"])
    assert_models_bit_equal(m, load_ply(p))


def test_ascii_rounds_decimals_to_nearest_float32(tmp_path):
    names = [c[0] for c in base_columns(1, 0)]
    rows = [["0.1"] * len(names), ["1e-50"] * len(names), ["-inf"] * len(names)]
    m = load_ply(_ascii_ply(tmp_path / "d.ply", names, rows))
    assert m.means[0, 0] == np.float32(0.1) and m.means[1, 0] == 0.0 and m.means[2, 0] == -np.inf


def test_error_ascii_truncated_or_not_numeric(tmp_path):
    names = [c[0] for c in base_columns(1, 0)]
    p = _ascii_ply(tmp_path / "t.ply", names, [["0"] * len(names)])
    p.write_text(p.read_text().replace("element vertex 1", "element vertex 2"))
    expect_error(p, "truncated", "2 vertex rows")
    p = _ascii_ply(tmp_path / "n.ply", names, [["0"] * (len(names) - 1) + ["zero"]])
    expect_error(p, "not numeric")
    # a blank line between rows, or a row wrapped over two lines, is named as such (it read as
    # "more data than declared")
    p = _ascii_ply(tmp_path / "b.ply", names, [["0"] * len(names)] * 3)
    head, _, data = p.read_text().partition("end_header\n")
    rows = data.splitlines()
    p.write_text(head + "end_header\n" + "\n".join([rows[0], "", *rows[1:]]) + "\n")
    expect_error(p, re.escape("row 2 (data line 2) is blank"))
    half = len(names) // 2
    wrapped = " ".join(rows[1].split()[:half]) + "\n" + " ".join(rows[1].split()[half:])
    p.write_text(head + "end_header\n" + "\n".join([rows[0], wrapped, rows[2]]) + "\n")
    expect_error(p, re.escape(f"row 2 (data line 2) holds {half} values, expected {len(names)}"))
    # whole rows past the declared count: refused with the binary reader's message
    p.write_text(head.replace("element vertex 3", "element vertex 2") + "end_header\n" + data)
    expect_error(p, "declares 2 vertices but the data holds 3: fix the header's element count")


def test_error_no_vertex_element(tmp_path):
    p = tmp_path / "nv.ply"
    p.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
        b"end_header\n\x03" + np.arange(3, dtype="<i4").tobytes()
    )
    expect_error(p, "no 'vertex' element", "face")


def test_error_missing_required_properties(tmp_path):
    cols = [c for c in base_columns() if c[0] not in ("opacity", "rot_3", "scale_1")]
    msg = expect_error(write_raw_ply(tmp_path / "m.ply", cols), "required", "opacity", "rot_3", "scale_1")
    assert "rot_2" not in msg and "x," not in msg


@pytest.mark.parametrize("count", [1, 8, 10, 15, 44, 46])
def test_error_bad_f_rest_count(tmp_path, count):
    p = write_raw_ply(tmp_path / "r.ply", base_columns(rest=count))
    expect_error(p, rf"\b{count}\b f_rest", r"\b0\b", r"\b9\b", r"\b24\b", r"\b45\b")


def test_error_f_rest_gaps(tmp_path):
    cols = [c for c in base_columns(rest=10) if c[0] != "f_rest_4"]  # 9 properties, 0..9 minus 4
    expect_error(write_raw_ply(tmp_path / "g.ply", cols), "gap", "f_rest_4")


def test_error_malformed_f_rest_name(tmp_path):
    cols = base_columns(rest=9) + [("f_rest_count", "<f4", np.zeros(3))]
    expect_error(write_raw_ply(tmp_path / "n.ply", cols), "f_rest_count")


def test_error_zero_primitives(tmp_path):
    expect_error(write_raw_ply(tmp_path / "z.ply", base_columns(n=0)), "zero primitives")


@pytest.mark.parametrize("cut", [1, 4, 4 * 59, 2 * 59 * 4 + 3, 3 * 59 * 4])
def test_error_truncated_data(tmp_path, cut):
    p = write_raw_ply(tmp_path / "t.ply", base_columns(n=3, rest=45))
    data = p.read_bytes()
    p.write_bytes(data[:-cut])
    expect_error(p, "truncated", r"\b3 vertices", "bytes")


def test_truncated_with_header_promising_more(tmp_path):
    p = write_raw_ply(tmp_path / "t2.ply", base_columns(n=3, rest=0), count=1000)
    expect_error(p, "truncated", "1000 vertices", "bytes")


def test_error_list_property_in_vertex(tmp_path):
    p = tmp_path / "lv.ply"
    hdr = "ply\nformat binary_little_endian 1.0\nelement vertex 1\n" + "".join(
        f"property float {name}\n" for name, _, _ in base_columns(1, 0)
    )
    hdr += "property list uchar int idx\nend_header\n"
    p.write_bytes(hdr.encode() + np.zeros(14, "<f4").tobytes() + b"\x00")
    expect_error(p, "list")
