"""seuwgpu: single-event-upset fault injection for 3D Gaussian splatting on WGSL compute shaders.

The public API (seuwgpu/api/) is importable from here: `import seuwgpu as sg; sg.render(...)`.
It is loaded on first use, so `import seuwgpu` and `seuwgpu --version` stay fast.
"""

from seuwgpu.errors import InputError, RunInUse, SeuwgpuError, TooBig
from seuwgpu.version import __version__

_API = (
    "DEFENSES",
    "FAULT_MODELS",
    "FIELDS",
    "FRAME_FORMATS",
    "MODEL_FORMATS",
    "PRECISIONS",
    "PROFILES",
    "Camera",
    "Injection",
    "Model",
    "Scene",
    "assemble_corpus",
    "cameras",
    "corpus_models",
    "default_spec",
    "defense_costs",
    "device_info",
    "export_scene",
    "inject",
    "list_scenes",
    "load_model",
    "make_report",
    "merge_runs",
    "outcome_rates",
    "plan_campaign",
    "read_records",
    "render_views",
    "report_figures",
    "run_campaign",
    "save_frames",
    "sort_first",
    "state_flips",
    "storm",
    "worst_case",
)

__all__ = ["InputError", "RunInUse", "SeuwgpuError", "TooBig", "__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        from seuwgpu import api

        return getattr(api, name)
    raise AttributeError(f"module 'seuwgpu' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
