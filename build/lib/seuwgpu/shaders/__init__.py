"""The WGSL compute shaders, one file per stage plus common.wgsl; installed as the resource
package `seuwgpu.shaders` (read with importlib.resources by seuwgpu/gpu/device.py)."""
