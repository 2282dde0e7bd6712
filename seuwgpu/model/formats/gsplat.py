"""gsplat checkpoints (`.pt` from gsplat's simple_trainer: {"step": ..., "splats": {...}}).

The `splats` state dict holds means [N, 3], scales [N, 3] (log), quats [N, 4] (w, x, y, z, not
normalised), opacities [N] (logit), sh0 [N, 1, 3] and shN [N, K, 3] (K = 0, 3, 8 or 15; gsplat's
coefficient-major layout, the same as Model.sh_rest). Reading a checkpoint needs torch
(pip install 'seuwgpu[torch]'); tensors are loaded on the CPU with weights_only=True.
"""

from __future__ import annotations

import os

import numpy as np

from seuwgpu.model.fields import Model
from seuwgpu.model.formats.base import ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError
from seuwgpu.model.formats.zips import shown_members

KEYS = ("means", "scales", "quats", "opacities", "sh0")
TORCH_HINT = "install torch (pip install 'seuwgpu[torch]') to read gsplat checkpoints"


class GsplatError(ModelFileError):
    """A gsplat checkpoint that cannot be read."""


def is_torch_file(head: bytes) -> bool:
    """torch.save output: a zip archive (PyTorch >= 1.6) or a legacy pickle."""
    return head[:4] == b"PK\x03\x04" or head[:2] in (b"\x80\x02", b"\x80\x04", b"\x80\x05")


def zip_problem(names: list[str]) -> str | None:
    """Why a zip archive with these members is no PyTorch checkpoint (None when it is one):
    torch.save writes a zip holding `<name>/data.pkl`; a .npz or a zipped output folder is something else."""
    if any(n == "data.pkl" or n.endswith("/data.pkl") for n in names):
        return None
    return (
        f"a zip archive that is no PyTorch checkpoint (it holds {shown_members(names)}): "
        "unpack it and give the model file inside"
    )


def model_from_splats(splats: dict, path: str = "") -> Model:
    """A Model from gsplat's `splats` dict (numpy arrays or anything np.asarray accepts)."""
    missing = [k for k in KEYS if k not in splats]
    if missing:
        raise GsplatError(f"{path}: the gsplat splats dict lacks {', '.join(missing)} (has {', '.join(splats)})")
    try:
        arr = {k: np.asarray(v, dtype=np.float32) for k, v in splats.items() if k in (*KEYS, "shN")}
    except (TypeError, ValueError) as e:
        raise GsplatError(f"{path}: the gsplat splats are not numeric arrays: {e}") from None
    n = arr["means"].shape[0] if arr["means"].ndim else 0
    if n == 0:
        raise GsplatError(f"{path}: the gsplat checkpoint holds zero splats")
    try:
        sh0 = arr["sh0"].reshape(n, 3)
        shn = arr.get("shN", np.zeros((n, 0, 3), np.float32)).reshape(n, -1, 3)
        return Model(
            means=arr["means"],
            log_scales=arr["scales"],
            quats=arr["quats"],
            opacity=arr["opacities"].reshape(n),
            sh_dc=sh0,
            sh_rest=shn,
        )
    except ValueError as e:
        raise GsplatError(f"{path}: gsplat splats have inconsistent shapes: {e}") from None


def read_gsplat(path) -> Model:
    spath = os.fspath(path)
    try:
        import torch
    except ImportError:
        raise GsplatError(f"{spath}: a PyTorch checkpoint; {TORCH_HINT}") from None
    try:
        ckpt = torch.load(spath, map_location="cpu", weights_only=True)
    except Exception as e:  # torch's own unpickling errors
        raise GsplatError(f"{spath}: torch could not load the checkpoint: {e}") from None
    splats = ckpt.get("splats") if isinstance(ckpt, dict) else None
    if splats is None and isinstance(ckpt, dict) and "means" in ckpt:
        splats = ckpt  # a bare splats state dict
    if not isinstance(splats, dict):
        raise GsplatError(f"{spath}: a PyTorch file without a gsplat 'splats' dict")
    return model_from_splats({k: v.detach().cpu().numpy() for k, v in splats.items()}, spath)


def _sniff(probe: Probe) -> bool:
    """A torch.save file; a zip that holds no data.pkl is refused with what it holds instead."""
    if not is_torch_file(probe.head):
        return False
    if probe.is_zip:
        members, zip_error = probe.zip_members()
        why = zip_error or zip_problem(members)
        if why:
            raise GsplatError(f"{probe.path}: {why}")
    return True


FORMAT = ModelFormat(
    name="gsplat",
    title="gsplat checkpoint",
    suffixes=(".pt", ".pth", ".ckpt"),
    up="-y",
    sniff=_sniff,
    read=lambda path: (read_gsplat(path), []),
)
