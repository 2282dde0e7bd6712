"""Frames larger than one storage binding: split into view groups or tile-row bands, bit-identical
to one submission (a small split limit forces the split at small sizes)."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.render.renderer import Renderer, render_split, split_plan


def test_split_plan():
    assert split_plan(8, 1920, 1080, 128 << 20) == (4, 1080)  # 8 views of 1080p: two submissions
    assert split_plan(3, 64, 48, 16 * 64 * 48 * 2) == (2, 48)
    assert split_plan(2, 64, 48, 16 * 64 * 20) == (1, 16)  # one view does not fit: 16-row bands
    with pytest.raises(ValueError, match="tile row"):
        split_plan(1, 64, 48, 100)


@pytest.mark.parametrize("size", [(64, 48), (50, 38)])
@pytest.mark.parametrize("limit_px", [64 * 48, 2 * 64 * 48 + 1, 64 * 16, 64 * 33])
def test_split_frames_are_bit_identical(size, limit_px):
    model = random_model(400, seed=9)
    model.log_scales[7, 0] = 4.5  # a frame-covering Gaussian crosses every band
    cams = orbit_cameras(3, *size)
    whole = Renderer(model, cams).render()
    split = render_split(model, cams, split_bytes=16 * limit_px)
    assert np.array_equal(whole.view(np.uint32), split.view(np.uint32))
