"""The records' schema: every column a campaign writes, its Arrow type, and the checks a part's
columns pass before it is read (campaign/store.py writes and reads the parts)."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from seuwgpu.errors import InputError

RECORD_SCHEMA = pa.schema(
    [
        ("campaign", pa.large_string()),  # single, dose or size
        ("scene", pa.large_string()),
        ("n_primitives", pa.int64()),
        ("precision", pa.large_string()),
        ("profile", pa.large_string()),
        ("field", pa.large_string()),
        ("primitive", pa.int64()),  # -1: several sites (a dose record)
        ("component", pa.int64()),
        ("bit", pa.int64()),
        ("bit_class", pa.large_string()),
        ("fault", pa.large_string()),
        ("clean_value", pa.float64()),
        ("corrupted_value", pa.float64()),
        ("defense", pa.large_string()),
        ("footprint", pa.float64()),  # a fraction of the pixels
        ("footprint_max", pa.float64()),
        ("peak_error", pa.float64()),
        ("psnr", pa.float64()),
        ("ssim", pa.float64()),
        ("lpips", pa.float64()),  # NaN: not measured
        ("nonfinite", pa.bool_()),
        ("catastrophic", pa.bool_()),
        ("outcome", pa.large_string()),
        ("clamps", pa.int64()),
        ("k", pa.int64()),
        ("repeat", pa.int64()),
        ("weight", pa.float64()),
        ("seed", pa.int64()),
        ("injection_id", pa.int64()),
        ("time_ms", pa.float64()),
    ]
)
"""The records' columns and their types: every part is written with them (`parquet_bytes`) and
checked against them when read (`check_part_schema`). A spec's `regions` add REGION_TYPE columns
regions_pred_P and regions_meas_P (bitmasks of the P sort-first regions reached in any view) and
REGION_SHARE_TYPE columns regions_pred_frame_P and regions_meas_frame_P (the share of regions one
frame reaches, averaged over the views)."""
REGION_TYPE = pa.int64()
REGION_SHARE_TYPE = pa.float64()
COLUMNS = RECORD_SCHEMA.names
# wall-clock measurements: the only columns a replay, a shard or a Ray worker may not reproduce
TIMED_COLUMNS = ("time_ms",)
REPRODUCIBLE_COLUMNS = [c for c in COLUMNS if c not in TIMED_COLUMNS]


def columns_of(ctx) -> list[str]:
    """The columns of a context's records: COLUMNS plus its sort-first contamination columns (the
    union over the views as bitmasks, and the share one frame reaches, averaged over the views)."""
    return COLUMNS + [
        f"regions_{kind}{frame}_{P}" for P in ctx.regions for frame in ("", "_frame") for kind in ("pred", "meas")
    ]


def check_record_columns(names, what: str):
    """Refuse names that are no record column (nor `run`, the label of a run), naming `what`."""
    unknown = [c for c in names if c != "run" and c not in COLUMNS]
    if unknown:
        known = ", ".join(["run", *COLUMNS])
        raise InputError(f"{what} {', '.join(unknown)}: not a record column (one of {known})")


def column_type(name: str) -> pa.DataType | None:
    """The type of a record column, None for a name no record has."""
    if name in COLUMNS:
        return RECORD_SCHEMA.field(name).type
    kind, _, p = name.removeprefix("regions_").partition("_")
    if name.startswith("regions_") and kind in ("pred", "meas"):
        if p.isdigit():
            return REGION_TYPE  # the union over the views: a bitmask of regions
        if p.startswith("frame_") and p.removeprefix("frame_").isdigit():
            return REGION_SHARE_TYPE  # the share of regions one frame reaches, averaged over views
    return None


def records_schema(columns) -> pa.Schema:
    """The schema of records holding `columns` (in that order); a name no record has is refused."""
    fields = []
    for c in columns:
        t = column_type(str(c))
        if t is None:
            raise InputError(
                f"{c!r} is not a record column (RECORD_SCHEMA, regions_pred_P/regions_meas_P, "
                "regions_pred_frame_P/regions_meas_frame_P)"
            )
        fields.append(pa.field(str(c), t))
    return pa.schema(fields)


def _kind(t: pa.DataType) -> str:
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        return "text"
    if pa.types.is_boolean(t):
        return "flag"
    if pa.types.is_integer(t) or pa.types.is_floating(t):
        return "number"
    return str(t)


def check_part_schema(path: Path, schema: pa.Schema | None = None) -> None:
    """Refuse a part whose record columns hold another kind of value (text, flag, number) than
    RECORD_SCHEMA says (a file some other tool wrote into records/), naming the part and the
    column. The kind, not the exact type: parts written by other tools with pandas (an integer
    column padded with NaN is float64, strings are string or large_string) stay readable."""
    if schema is None:
        try:
            schema = pq.read_schema(path)
        except (OSError, ValueError) as e:  # pyarrow's ArrowInvalid is a ValueError
            raise InputError(f"{path}: not a readable record part ({e})") from None
    for f in schema:
        want = column_type(f.name)
        if want is not None and _kind(f.type) != _kind(want):
            why = f"records hold {want} ({_kind(want)}): not a seuwgpu record part"
            raise InputError(f"{path}: column {f.name} holds {f.type}, {why}")
