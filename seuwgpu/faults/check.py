"""Check stage: shaders/check.wgsl, the per-primitive checks of the parity, checksum and
scale-class defenses over a renderer's stored chunks; twin: faults/defenses.py `detect`.

The side data (one u32 per primitive) is computed from the clean model once, like the guard's
box. A check is one dispatch per chunk and one 4-byte read of the detection count; only when it is
non-zero does the host read the flags and repair (cull, reload or clamp: defenses.repair).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.guard import fill_chunk_params
from seuwgpu.gpu.device import STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms

# shaders/check.wgsl's MODE_PARITY, MODE_CHECKSUM, MODE_SCALE, per kind of check; the defenses are
# defenses.CHECKED (a checked defense of a new kind fails here, at import, until it has a mode)
_KIND_MODE = {"parity": 0, "checksum": 1, "scalebound": 2}
MODES = {d: _KIND_MODE["parity" if d.startswith("parity") else d] for d in dfn.CHECKED}


class Checker:
    """One defense's check over a renderer's stored chunks (`run` -> flagged count, `flags`)."""

    def __init__(self, renderer, defense: str, clean_rows: np.ndarray, box=None):
        if defense not in MODES:
            raise ValueError(f"defense {defense!r} has no GPU check; checked ones: {', '.join(MODES)}")
        r, L = renderer, renderer.layout
        g = self.gpu = r.gpu
        self.layout, self.chunks, self.defense = L, r.chunks, defense
        self.kernel = Kernel(g, "check")
        side = dfn.side_data(defense, clean_rows, L.precision, L.degree, box)
        self.side = g.upload(side.astype(np.uint32))
        table = dfn.scale_table(box, L.precision) if defense == "scalebound" else np.zeros(4, np.float32)
        self.table = g.upload(np.asarray(table, np.float32))
        self.out = g.buffer(16 + 4 * L.n, STORAGE, "check.out")
        self.params = Uniforms(g, self.kernel.struct("CheckParams"), L.n_chunks, "check.params")
        fill_chunk_params(
            self.params,
            L,
            mode=MODES[defense],
            ways=1 if defense == "parity" else 4,
            cover=dfn.parity_cover_mask(L.precision),
            comp_count=dfn.parity_components(defense, L.degree),
        )
        self.params.write()
        self.zero = np.zeros(4, np.uint32)

    def encode(self, enc):
        for k in range(self.layout.n_chunks):
            self.kernel.dispatch(
                enc,
                params=self.params.binding(k),
                side=self.side,
                words=self.chunks[k],
                table=self.table,
                out=self.out,
                threads=self.layout.chunk_range(k)[1] - self.layout.chunk_range(k)[0],
            )

    def run(self) -> int:
        """Check every primitive; returns how many are flagged (one small read)."""
        self.gpu.write(self.out, self.zero)
        enc = self.gpu.device.create_command_encoder()
        self.encode(enc)
        self.gpu.submit(enc)
        return int(self.gpu.read(self.out, np.uint32, 0, 4)[0])

    def flags(self) -> np.ndarray:
        return self.gpu.read(self.out, np.uint32, 16, 4 * self.layout.n).astype(bool)
