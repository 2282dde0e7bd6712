"""Zip archives as model containers (a bundled SOG, a torch.save checkpoint): listed once, named
in error messages the same way."""

from __future__ import annotations

import zipfile


def zip_members(path) -> list[str]:
    """The member names of a zip archive; ValueError says why it cannot be listed."""
    try:
        with zipfile.ZipFile(path) as z:
            return z.namelist()
    except (zipfile.BadZipFile, OSError) as e:
        raise ValueError(f"a broken zip archive ({e}; truncated?)") from None


def shown_members(names: list[str]) -> str:
    """The first few member names, for a message about what an archive holds."""
    return ", ".join(names[:5]) + (", ..." if len(names) > 5 else "") or "nothing"
