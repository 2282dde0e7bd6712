"""Flips stage: shaders/flip.wgsl, batched XORs on the stored words of a GPU-resident model, and
its numpy twin `xor_words`.

A flip is an XOR, so applying the same (word, mask) list again restores the words exactly. The
host merges masks per word (faults/engine.py), so no two threads touch one word.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.device import GPU, STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms


class Flips:
    """XOR (word, mask) lists into model chunks (GPU buffers of u32 words), one submission per
    call; the pair buffers grow on demand and are reused across calls."""

    def __init__(self, gpu: GPU, chunks: list):
        self.gpu, self.chunks = gpu, list(chunks)
        self.kernel = Kernel(gpu, "flip")
        self.record = self.kernel.struct("Flip")
        self.params = Uniforms(gpu, self.kernel.struct("FlipParams"), len(self.chunks), "flip.params")
        self.capacity = 0

    def apply(self, xors: dict[int, np.ndarray]):
        """XOR every pair of `xors` ({chunk: u32 [m, 2] (word, mask)}) into its chunk."""
        if not xors:
            return
        enc = self.gpu.device.create_command_encoder()
        self.encode(enc, xors)
        self.gpu.submit(enc)

    def encode(self, enc, xors: dict[int, np.ndarray]):
        """Record the XORs into `enc` (their lists are uploaded now, so they land before the
        submission): lets a flip sit between two stages of one frame."""
        g = self.gpu
        need = max(len(p) for p in xors.values())
        if self.capacity < need:
            self.capacity = max(need, 1024)
            self.pairs = [g.buffer(self.record.size * self.capacity, STORAGE, "flip.pairs") for _ in self.chunks]
        self.params.rows["count"] = 0
        for ch, pairs in xors.items():
            recs = self.record.zeros(len(pairs))
            self.record.fill(recs, word=pairs[:, 0], mask=pairs[:, 1])
            g.write(self.pairs[ch], recs)
            self.params.rows["count"][ch] = len(pairs)
        self.params.write()
        for ch, pairs in xors.items():
            self.kernel.dispatch(
                enc, params=self.params.binding(ch), flips=self.pairs[ch], words=self.chunks[ch], threads=len(pairs)
            )


def xor_words(words: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Twin of the flip kernel: `words` (u32) with every (word, mask) pair XORed in."""
    out = np.array(words, dtype=np.uint32, copy=True)
    pairs = np.asarray(pairs, dtype=np.uint32).reshape(-1, 2)
    np.bitwise_xor.at(out, pairs[:, 0].astype(np.int64), pairs[:, 1])
    return out
