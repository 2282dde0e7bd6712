"""The `info` command: the adapter in use."""

from __future__ import annotations

import argparse

from seuwgpu.apps.cli.command import Command


# ---- info -------------------------------------------------------------------------------------------
def info_arguments(s: argparse.ArgumentParser):
    pass


def cmd_info(args):
    from seuwgpu import api

    info = api.device_info()
    print(f"adapter: {info['device']} ({info['vendor']})")
    print(f"backend: {info['backend']}  type: {info['adapter_type']}  driver: {info['driver']}")
    feats = info["features"]
    print("features that matter: " + ", ".join(f for f in ("shader-f16", "timestamp-query", "subgroup") if f in feats))
    for k in (
        "max-storage-buffer-binding-size",
        "max-buffer-size",
        "max-compute-workgroup-storage-size",
        "max-compute-invocations-per-workgroup",
        "max-compute-workgroups-per-dimension",
        "max-storage-buffers-per-shader-stage",
    ):
        print(f"{k}: {info['limits'].get(k)}")
    return 0


INFO = Command("info", "adapter, backend, features and limits in use", info_arguments, cmd_info)
