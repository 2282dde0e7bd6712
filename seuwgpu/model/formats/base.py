"""What a model-file format is to the loader: one `ModelFormat` object per format module.

Each format module (ply.py, spz.py, ...) ends with `FORMAT = ModelFormat(...)`, and
`formats/__init__.py` lists those objects once, in REGISTRY. detect_format, read_model,
save_model, model_label and the "unrecognised model file" message all loop over that list, so
adding a format is one module and one line there (CONTRIBUTING.md, "Add a model format").
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field

from seuwgpu.model.fields import Model
from seuwgpu.model.formats import zips

ANTIALIASED_NOTE = "trained antialiased (mip-splatting): rendered here without the opacity compensation"
HEAD_BYTES = 4096  # how much of a file the sniffers see
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass
class Probe:
    """What a sniffer looks at: the path, the file's size and first HEAD_BYTES bytes; a zip's
    member list is read once, for whichever sniffer asks first."""

    path: str
    size: int
    head: bytes
    _zip: tuple[list[str], str | None] | None = field(default=None, repr=False)

    @classmethod
    def of(cls, path: str) -> Probe:
        with open(path, "rb") as f:
            return cls(path, os.path.getsize(path), f.read(HEAD_BYTES))

    def named(self, suffixes: tuple[str, ...]) -> bool:
        """Whether the file's name ends with one of these suffixes (case-insensitive)."""
        return self.path.lower().endswith(suffixes)

    @property
    def is_zip(self) -> bool:
        return self.head[:4] == b"PK\x03\x04"

    def zip_members(self) -> tuple[list[str], str | None]:
        """(member names, None) of a zip archive, or ([], why it cannot be listed)."""
        if self._zip is None:
            try:
                self._zip = (zips.zip_members(self.path), None)
            except ValueError as e:
                self._zip = ([], str(e))
        return self._zip


@dataclass(frozen=True)
class ModelFormat:
    """One model-file format.

    - `sniff(probe)`: True when the content is this format. It raises ModelFileError instead when
      the file's name claims the format (its suffix) but the content says why it is not one, so
      that the user hears that reason rather than "unrecognised". Sniffers run in REGISTRY order
      and the first True wins: a format without a magic number (.splat) goes last.
    - `read(path) -> (Model, notes)`: the notes are short lines worth telling the user (a
      version, a compression level, an antialiased flag).
    - `write(model, path, up=None, **options)` or None for a read-only format; `up` is the
      model's up axis, which the writer records or turns the model to.
    - `up`: the axis the format's convention puts up (framing without cameras); `recorded_up(path)`
      the axis a file records itself, if the format has a place for one (PLY's `comment up`).
    - `read_level(path, level) -> (Model, notes)`: a format holding several levels of detail (a
      PlayCanvas LOD set) reads the one asked for (`--lod N`); None for every other format, which
      refuses a level.
    - `hint`: a clause for the "unrecognised model file" message when sniffing needs help (the
      headerless .splat is recognised by its extension).
    - `exact`: its writer keeps every value as it is (float32, no quantisation, NaN kept): the
      file a faulted model is always written to, and the first a refusal suggests.
    """

    name: str
    title: str
    suffixes: tuple[str, ...]
    up: str
    sniff: Callable[[Probe], bool]
    read: Callable[[str], tuple[Model, list[str]]]
    write: Callable[..., None] | None = None
    recorded_up: Callable[[str], str | None] | None = None
    read_level: Callable[[str, int], tuple[Model, list[str]]] | None = None
    hint: str = ""
    exact: bool = False
