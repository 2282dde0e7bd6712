"""Check stage: shaders/check.wgsl, the per-primitive checks of the parity, checksum and
scale-class defenses over a renderer's stored chunks; twin: faults/defenses.py `detect`.

The side data is computed from the clean model once, like the guard's box, and uploaded packed
(`side_bits` per primitive, side.pack_side), so the device holds what the memory column
charges (side.device_bytes). A check is one dispatch per chunk and one 4-byte read of the
detection count; only when it is non-zero does the host read the flag bits and repair (cull,
reload or clamp: defenses.repair), and clear them for the next check.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults import side as sd
from seuwgpu.faults.guard import fill_chunk_params
from seuwgpu.gpu.device import STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms


class Checker:
    """One defense's check over a renderer's stored chunks (`run` -> flagged count, `flags`)."""

    def __init__(self, renderer, defense: str, clean_rows: np.ndarray, box=None):
        d = dfn.checked(defense)
        r, L = renderer, renderer.layout
        g = self.gpu = r.gpu
        self.layout, self.chunks, self.defense = L, r.chunks, defense
        self.kernel = Kernel(g, "check")
        side = d.side_data(np.asarray(clean_rows), L.precision, L.degree, box)
        self.side = g.upload(sd.pack_side(side, d.side_bits))
        self.table = g.upload(np.asarray(d.check_table(box, L.precision), np.float32))
        self.flag_words = -(-L.n // 32)
        self.out = g.buffer(sd.CHECK_HEADER_BYTES + 4 * self.flag_words, STORAGE, "check.out")
        self._flagged = False  # flag bits set by the last run (cleared before the next)
        self.params = Uniforms(g, self.kernel.struct("CheckParams"), L.n_chunks, "check.params")
        fill_chunk_params(
            self.params,
            L,
            mode=self.kernel.const(d.check_mode),
            side_bits=d.side_bits,
            **d.check_parameters(L.precision, L.degree),
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
        if self._flagged:
            self.gpu.write(self.out, np.zeros(4 + self.flag_words, np.uint32))
        else:
            self.gpu.write(self.out, self.zero)
        enc = self.gpu.device.create_command_encoder()
        self.encode(enc)
        self.gpu.submit(enc)
        count = int(self.gpu.read(self.out, np.uint32, 0, 4)[0])
        self._flagged = count > 0
        return count

    def flags(self) -> np.ndarray:
        """[n] bool: the primitives the last run flagged."""
        words = self.gpu.read(self.out, np.uint32, sd.CHECK_HEADER_BYTES, 4 * self.flag_words)
        return np.unpackbits(words.view(np.uint8), bitorder="little")[: self.layout.n].astype(bool)

    def device_bytes(self) -> int:
        """Bytes of this check's buffers on the device (side.device_bytes counts the same)."""
        return int(self.side.size + self.table.size + self.out.size + self.params.buffer.size)
