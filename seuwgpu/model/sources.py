"""Where a model and its views come from, resolved the same way by every command (render,
inject, campaign, viewer): an embedded scene or a model file, then the capture's cameras when
given (K of them evenly with `views`), else the scene's registered orbit (procedural scenes) or
the robust framing of model/framing.py, and at last `scale` applied to the resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from seuwgpu.model import checks, scenes
from seuwgpu.model.budget import RENDER_BYTES_PER_VALUE, SCENE_BYTES_PER_VALUE, check_scene
from seuwgpu.model.cameras import Camera, load_cameras, scale_cameras, select_views
from seuwgpu.model.captures import capture_antialiased
from seuwgpu.model.fields import Model
from seuwgpu.model.formats import ANTIALIASED_NOTE, read_model
from seuwgpu.model.framing import AXES, orbit_views


@dataclass
class Source:
    """A loaded model with its display name, the up axis its framing uses and notes for the user."""

    model: Model
    name: str
    up: str
    scene: str | None = None  # the embedded scene framed by its registered views (None: a file, or --up given)
    notes: list[str] = field(default_factory=list)
    format: str | None = None  # the file's format (formats.REGISTRY name); None: an embedded scene


def load_source(
    scene: str | None = None,
    path=None,
    n: int | None = None,
    sh_degree: int = 3,
    seed: int = 0,
    up: str | None = None,
    lod: int | None = None,
) -> Source:
    """An embedded scene (procedural or real capture) by name, or any supported model file
    (`lod`: the level of a PlayCanvas LOD set; refused for another file or a scene)."""
    if up is not None:
        checks.one_of(up, "up axis", AXES)
    if path is not None:
        mf = read_model(path, lod=lod)
        return Source(mf.model, mf.name, up or mf.up, None, mf.notes, mf.format)
    name = scene or scenes.DEFAULT_SCENE
    checks.lod_of_a_model_file(lod, name)
    if n is not None and not scenes.is_capture(name):
        # before generating: enough memory to generate and render it (an engine checks its own
        # copies: faults/engine.py, campaign specs: campaign/budget.py)
        check_scene(n, sh_degree, "--n", max(SCENE_BYTES_PER_VALUE, RENDER_BYTES_PER_VALUE), "render")
    model = scenes.make_scene(name, n=n, sh_degree=sh_degree, seed=seed)
    registered = "+y" if scenes.is_capture(name) else "+z"
    notes = [ANTIALIASED_NOTE] if scenes.is_capture(name) and capture_antialiased(name) else []
    return Source(model, name, up or registered, name if up in (None, registered) else None, notes)


def source_views(
    source: Source,
    cameras=None,
    views: int | None = None,
    size: tuple[int, int] = (256, 256),
    scale: float | None = None,
    default_views: int = 4,
) -> list[Camera]:
    """The views to render: a camera file's (all, or `views` of them evenly), else `views` (or
    `default_views`) orbit views of `size` pixels; then `scale` times the resolution."""
    if views is not None and views < 1:
        raise ValueError(f"views must be at least 1, got {views}")
    if cameras is not None:
        cams = select_views(load_cameras(Path(cameras)), views)
    else:
        k, (w, h) = views or default_views, size
        if source.scene is not None:
            cams = scenes.scene_cameras(source.scene, k, w, h)
        else:
            cams = orbit_views(source.model.means, k, w, h, up=source.up, log_scales=source.model.log_scales)
    return scale_cameras(cams, scale) if scale not in (None, 1, 1.0) else cams
