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


class Checker:
    """One defense's check over a renderer's stored chunks (`run` -> flagged count, `flags`)."""

    def __init__(self, renderer, defense: str, clean_rows: np.ndarray, box=None):
        d = dfn.checked(defense)  # its check_mode is shaders/check.wgsl's MODE_*
        r, L = renderer, renderer.layout
        g = self.gpu = r.gpu
        self.layout, self.chunks, self.defense = L, r.chunks, defense
        self.kernel = Kernel(g, "check")
        side = d.side_data(np.asarray(clean_rows), L.precision, L.degree, box)
        self.side = g.upload(side.astype(np.uint32))
        self.table = g.upload(np.asarray(d.check_table(box, L.precision), np.float32))
        self.out = g.buffer(16 + 4 * L.n, STORAGE, "check.out")
        self.params = Uniforms(g, self.kernel.struct("CheckParams"), L.n_chunks, "check.params")
        fill_chunk_params(
            self.params,
            L,
            mode=d.check_mode,
            **d.check_parameters(L.precision, L.degree),
        )
        self.params.write()
        self.zero = np.zeros(4, np.uint32)

    def encode(self, enc):
        for k in range(self.layout.n_chunks):
            self.kernel.dispatch(
                enc,
                {0: self.params.binding(k), 1: self.side, 2: self.chunks[k], 3: self.table, 4: self.out},
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
