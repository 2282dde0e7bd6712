"""Check stage: shaders/check.wgsl, the per-primitive checks of the parity, checksum and
scale-class defenses over a renderer's stored chunks; twin: faults/defenses.py `detect`.

The side data is computed from the clean model once, like the guard's box, and uploaded packed
(`side_bits` per primitive, side.pack_side), so the device holds what the memory column
charges (side.device_bytes). A check is one dispatch per chunk and one 4-byte read of the
detection count; only when it is non-zero does the host read the flag bits and repair (cull,
reload or clamp: defenses.repair), and clear them for the next check.

The checker's own state (issue 47): its parameters carry a seal (`seal_words`, a hash of every
parameter and of the table) that the shader verifies; a mismatch (an upset in the uniform
buffer) makes `run` rewrite the parameters from the host's copy and check again
(`param_faults` counts them). The detection count is kept twice, so one upset in it cannot hide
a detection. What one upset in the side data or the flag bits does is stated in
docs/defenses.md and measured by tools/checker_state.py.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults import side as sd
from seuwgpu.faults.codes import CHECKSUM_SEED, fmix32
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
        table = np.asarray(d.check_table(box, L.precision), np.float32)
        self.table = g.upload(table)
        self.flag_words = -(-L.n // 32)
        self.out = g.buffer(sd.CHECK_HEADER_BYTES + 4 * self.flag_words, STORAGE, "check.out")
        self._flagged = False  # flag bits set by the last run (cleared before the next)
        self.params = Uniforms(g, self.kernel.struct("CheckParams"), L.n_chunks, "check.params")
        fill_chunk_params(
            self.params,
            L,
            mode=self.kernel.const(d.check_mode),
            side_bits=d.side_bits,
            table_len=table.size,
            **d.check_parameters(L.precision, L.degree),
        )
        self.params.rows["seal"] = seal_words(self.params.rows, table)
        self.params.write()
        self.zero = np.zeros(4, np.uint32)
        self.param_faults = 0  # runs that found their parameters upset (and were rerun)

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
        """Check every primitive; returns how many are flagged (one small read). Parameters found
        upset are rewritten from the host's copy and the check run again."""
        for _ in range(2):
            if self._flagged:
                self.gpu.write(self.out, np.zeros(4 + self.flag_words, np.uint32))
            else:
                self.gpu.write(self.out, self.zero)
            enc = self.gpu.device.create_command_encoder()
            self.encode(enc)
            self.gpu.submit(enc)
            head = self.gpu.read(self.out, np.uint32, 0, 12)
            count = int(max(head[0], head[1]))  # kept twice: an upset in one copy hides nothing
            self._flagged = True  # flags may be set: cleared before the next run
            if not head[2]:
                break
            self.param_faults += 1
            self.params.write()
        self._flagged = count > 0 or bool(head[2])
        return count

    def flags(self) -> np.ndarray:
        """[n] bool: the primitives the last run flagged."""
        words = self.gpu.read(self.out, np.uint32, sd.CHECK_HEADER_BYTES, 4 * self.flag_words)
        return np.unpackbits(words.view(np.uint8), bitorder="little")[: self.layout.n].astype(bool)

    def device_bytes(self) -> int:
        """Bytes of this check's buffers on the device (side.device_bytes counts the same)."""
        return int(self.side.size + self.table.size + self.out.size + self.params.buffer.size)


def seal_words(rows: np.ndarray, table: np.ndarray) -> np.ndarray:
    """[slots] u32: each CheckParams slot's seal, h = fmix32(h ^ word) over its words before the
    seal, then over the table's words (twin of shaders/check.wgsl params_seal)."""
    fields = [f for f in rows.dtype.names if f != "seal"]
    h = np.full(rows.shape[0], CHECKSUM_SEED, np.uint64)
    for f in fields[: fields.index("table_len") + 1]:
        h = fmix32(h ^ rows[f].astype(np.uint64))
    for w in np.asarray(table, np.float32).view(np.uint32):
        h = fmix32(h ^ np.uint64(w))
    return h.astype(np.uint32)
