"""seuwgpu: single-event-upset fault injection for 3D Gaussian splatting on WGSL compute shaders."""

from seuwgpu.errors import InputError, RunInUse, SeuwgpuError, TooBig
from seuwgpu.version import __version__

__all__ = ["InputError", "RunInUse", "SeuwgpuError", "TooBig", "__version__"]
