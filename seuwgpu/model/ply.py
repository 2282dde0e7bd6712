"""Kept for existing imports: the INRIA PLY reader and writer live in `seuwgpu.model.formats.ply`."""

from seuwgpu.model.formats.ply import (  # noqa: F401
    REQUIRED_PROPERTIES,
    PlyError,
    inria_property_names,
    load_ply,
    save_ply,
)
