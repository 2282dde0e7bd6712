"""Decode stage: shaders/decode.wgsl, the shaders' own decode of stored words, for tests and
inspection. Twin: model/encoding.py `from_bits` (bit for bit)."""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import PRECISION_CODE
from seuwgpu.gpu.device import GPU, UNIFORM, get_gpu
from seuwgpu.gpu.kernel import Kernel
from seuwgpu.model import encoding


def gpu_decode(words: np.ndarray, precision: str, gpu: GPU | None = None) -> np.ndarray:
    """Decode raw stored words (u32; two values per word for 16-bit precisions) to float32 with
    the shaders' decode_value."""
    gpu = gpu or get_gpu()
    words = np.ascontiguousarray(words, dtype=np.uint32).reshape(-1)
    count = words.size * (2 if encoding.bits_per_value(precision) == 16 else 1)
    kernel = Kernel(gpu, "decode")
    params = gpu.upload(kernel.struct("DecodeParams").pack(count=count, fmt=PRECISION_CODE[precision]), UNIFORM)
    src = gpu.upload(words)
    dst = gpu.buffer(4 * count)
    enc = gpu.device.create_command_encoder()
    kernel.dispatch(enc, params=params, words=src, values=dst, threads=count)
    gpu.submit(enc)
    return gpu.read(dst, np.float32, 0, 4 * count)
