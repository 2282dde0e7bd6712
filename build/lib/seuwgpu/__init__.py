"""seuwgpu: single-event-upset fault injection for 3D Gaussian splatting on WGSL compute shaders."""

from seuwgpu.version import __version__

__all__ = ["__version__"]
