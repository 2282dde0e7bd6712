from seuwgpu.gpu.device import GPU, get_gpu  # noqa: F401
