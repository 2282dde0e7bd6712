"""seuwgpu: single-event-upset fault injection for 3D Gaussian splatting on WGSL compute shaders."""

__version__ = "0.1.0"
