"""A battery of bad inputs, interruptions and oversized jobs against the `seuwgpu` command line.

Each case runs one command (in this process through `main(argv)`, or as a real process where a
kill or a second process is the point) and its outcome is classified:

- clear error:  exit status 2 (3 for `view` without a display), one line saying `error:`, no traceback
- correct:      exit status 0 and the result checked (a render of the right size, records equal to an
                uninterrupted reference run, a manifest listing what is missing, ...)
- refused:      a clear error where a correct result was expected (a valid input refused)
- traceback:    an exception escaped (a Python traceback)
- crash:        killed by a signal, hung past its timeout, or another exit status
- silent wrong: exit status 0 where an error was due, or a result that fails its check

    python tools/robustness_battery.py --out battery.json [--only SUBSTRING] [--work DIR]

prints a table per class and category and writes every case (argv, outcome, the stderr's last line)
as JSON to --out. Kill-and-resume cases need seconds each (those of storm and state about 20 s); the
whole battery takes about 6 minutes on two cores.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "data" / "formats"  # the .ksplat and SOG fixtures the model cases start from
sys.path.insert(0, str(ROOT))

from seuwgpu.apps.cli import main  # noqa: E402
from seuwgpu.campaign import store  # noqa: E402
from seuwgpu.model.cameras import save_cameras  # noqa: E402
from seuwgpu.model.formats import save_model  # noqa: E402
from seuwgpu.model.scenes import make_scene, scene_cameras  # noqa: E402


@dataclass
class Case:
    category: str
    name: str
    argv: list
    expect: str = "error"  # "error" | "ok"
    check: object = None  # callable(stdout) -> None, raising AssertionError when the result is wrong
    process: bool = False  # run as a real process
    env: dict = field(default_factory=dict)
    before: object = None  # callable run just before the case (damage a run directory, change a file)
    kill: tuple | None = None  # (signal, seconds, times): interrupt that often, then run to the end
    concurrent: bool = False  # start a first campaign on the same --out, then this one
    # what a kill waits for before its `seconds`: "part" (a campaign wrote a new part), "lock" (a
    # storm or state run holds its folder: it is past its arguments and loading), "save" (a storm
    # or state run rewrote its partial file while running, every 10 s)
    kill_after: str = "part"
    stderr_has: str = ""  # text the command's stderr must hold (a note) for a correct outcome
    needs: str = ""  # the name of a case whose result this one reads (run with it under --only)


@dataclass
class Outcome:
    rc: int | None
    out: str
    err: str
    traceback: bool = False
    timeout: bool = False
    notes: str = ""
    wrong: str = ""  # a fault seen between the interrupts (a damaged part, no partial records kept)


TOP = {"views": "1", "size": '"16x16"', "batch": "4"}
SCENE = 'scene = "spheres"\nn = 60\n'
SINGLE = {"fields": '["opacity"]', "bits": "[30]", "samples": "2", "defenses": '["none"]'}


def table(name: str, base: dict, **over) -> str:
    """A TOML table from base values with some replaced (None: left out)."""
    vals = {**base, **over}
    return f"[{name}]\n" + "".join(f"{k} = {v}\n" for k, v in vals.items() if v is not None)


def spec_text(top=None, scene=None, single=None, extra=""):
    """A tiny valid spec, with top-level values replaced (`top`: {key: TOML value}), another scene
    entry, another [single] table ("" for none) and extra tables."""
    head = "".join(f"{k} = {v}\n" for k, v in {**TOP, **(top or {})}.items() if v is not None)
    return (
        head
        + "[[scenes]]\n"
        + (SCENE if scene is None else scene)
        + (table("single", SINGLE) if single is None else single)
        + extra
    )


def strip_run_meta(path: Path):
    """Rewrite a partial file without the run's arguments in its metadata (as before they were kept)."""
    import pyarrow.parquet as pq

    from seuwgpu.campaign.partial import RUN_META

    table = pq.read_table(path)
    meta = {k: v for k, v in (table.schema.metadata or {}).items() if k != RUN_META}
    pq.write_table(table.replace_schema_metadata(meta), path)


def webp_claiming(width: int, height: int) -> bytes:
    """A lossless WebP of 16 x 16 texels whose header claims width x height (no data for them)."""
    buf = io.BytesIO()
    Image.fromarray(np.zeros((16, 16, 4), np.uint8)).save(buf, "WEBP", lossless=True)
    b = bytearray(buf.getvalue())
    assert b[12:16] == b"VP8L" and b[20] == 0x2F
    bits = struct.unpack_from("<I", b, 21)[0] & ~0xFFFFFFF
    struct.pack_into("<I", b, 21, bits | (width - 1) | (height - 1) << 14)
    return bytes(b)


def crc_broken(zip_bytes: bytes, member: str) -> bytes:
    """A zip whose `member`'s stored bytes no longer match its CRC (one byte flipped)."""
    with zipfile.ZipFile(io.BytesIO(zip_bytes)) as z:
        info = z.getinfo(member)
    b = bytearray(zip_bytes)
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    b[start + info.compress_size // 2] ^= 0xFF
    assert zlib.crc32(b[start : start + info.compress_size]) != info.CRC
    return bytes(b)


class Battery:
    def __init__(self, work: Path):
        self.work = work
        self.cases: list[Case] = []
        self.n = 0

    def fresh(self, stem: str) -> Path:
        self.n += 1
        return self.work / f"{stem}{self.n}"

    def add(self, *a, **k):
        self.cases.append(Case(*a, **k))

    # ---- set-up --------------------------------------------------------------------------------
    def files(self):
        w = self.work
        model = make_scene("spheres", n=80, seed=4)
        save_model(model, w / "good.ply")
        save_model(model, w / "good.spz")
        self.good_ply = (w / "good.ply").read_bytes()
        save_cameras(scene_cameras("spheres", 2, 16, 16), w / "cams.json")
        (w / "file").write_text("a file, not a folder")
        (w / "empty").write_bytes(b"")
        (w / "dir").mkdir()

    # ---- checks --------------------------------------------------------------------------------
    @staticmethod
    def npz_shape(path, shape):
        def check(_out):
            images = np.load(path)["images"]
            assert images.shape == shape, images.shape
            assert np.isfinite(images).all()

        return check

    @staticmethod
    def npz_like(path, ref, shape, tol=0.02):
        """A render of `shape`, finite, within `tol` of the render in `ref` (at most 1/255 mean)."""

        def check(_out):
            images = np.load(path)["images"]
            assert images.shape == shape, images.shape
            assert np.isfinite(images).all()
            diff = np.abs(images - np.load(ref)["images"])
            assert diff.max() <= tol and diff.mean() <= 1 / 255, (float(diff.max()), float(diff.mean()))

        return check

    @staticmethod
    def bit_flipped(out, bit):
        """inject's corrupted value is its clean one with `bit` flipped (float32), and the panel is written."""

        def check(stdout):
            lines = dict(line.split(": ", 1) for line in stdout.splitlines() if ": " in line)
            clean = np.float32(lines["clean_value"])
            want = (clean.view(np.uint32) ^ np.uint32(1 << bit)).view(np.float32)
            assert np.isfinite(clean) and np.isclose(float(lines["corrupted_value"]), want, rtol=1e-6), lines
            assert (out / "panel.png").is_file()

        return check

    @staticmethod
    def records_of(run, n, scene):
        """A campaign's records: n of them, of the scene named `scene`, with finite metrics."""

        def check(_out):
            r = store.read_records(run)
            assert len(r) == n and set(r["scene"]) == {scene}, (len(r), set(r["scene"]))
            assert np.isfinite(r["footprint"]).all()

        return check

    # ---- cases ---------------------------------------------------------------------------------
    def spec_cases(self):
        bad_top = {
            "seed": ["-1", "1.5", "true", '"x"', "18446744073709551616"],
            "views": ["0", "-3", "65", "1.5", "true", '"4"'],
            "size": ['"0x0"', '"15x16"', '"abc"', "[16]", "[16.5, 16]", '"16x16x16"', "5"],
            "scale": ["0", "-1", "17", "true", '"x"', "nan", "inf"],
            "batch": ["0", "65537", "1.5", "true"],
            "name": ["5", '""'],
            "bogus": ["1"],
        }
        good_top = {"seed": ["5"], "views": ["3"], "size": ['"16x32"', "[32, 16]"], "scale": ["0.5"], "batch": ["1"]}
        for key, vals in bad_top.items():
            for v in vals:
                self.plan_case(f"{key} = {v}", spec_text(top={key: v}), "error")
        for key, vals in good_top.items():
            for v in vals:
                self.plan_case(f"{key} = {v}", spec_text(top={key: v}), "ok")
        bad_scene = [
            'scene = "nope"',
            "scene = 5",
            'scene = "spheres"\nn = 0',
            'scene = "spheres"\nn = -1',
            'scene = "spheres"\nn = 1.5',
            'scene = "spheres"\nn = true',
            'scene = "spheres"\nsh_degree = 4',
            'scene = "spheres"\nsh_degree = -1',
            'scene = "spheres"\nmodel = "good.ply"',
            'model = "good.ply"\nply = "good.ply"',
            'model = "good.ply"\nn = 50',
            "ply = 5",
            'model = "missing.ply"',
            'model = "dir"',
            'model = "."',
            'scene = "spheres"\ncameras = "missing.json"',
            'scene = "spheres"\ncameras = 5',
            'scene = "spheres"\nup = "q"',
            'scene = "spheres"\nup = 3',
            'scene = "spheres"\nseed = -1',
            'scene = "spheres"\nbogus = 1',
            "n = 5",
        ]
        for s in bad_scene:
            self.plan_case(s.replace("\n", "; "), spec_text(scene=s + "\n"), "error")
        for s in ('model = "good.ply"', 'ply = "good.spz"'):
            self.plan_case(s.replace("\n", "; "), spec_text(scene=s + "\n"), "ok")
        cams = 'scene = "spheres"\ncameras = "cams.json"\n'  # the camera file's size rules: no size =
        self.plan_case("scene with cameras, no size", spec_text(top={"size": None}, scene=cams), "ok")
        self.plan_case("scene with cameras, and size (ignored: refused)", spec_text(scene=cams), "error")
        self.plan_case("no scenes", "views = 1\n" + table("single", SINGLE), "error")
        self.plan_case("scenes = 5", "scenes = 5\n" + table("single", SINGLE), "error")
        self.plan_case("no campaign table", spec_text(single=""), "error")
        single = {
            "precisions": ['["fp64"]', "[]", '"fp32"', '["fp32", "fp32"]'],
            "fields": ['["nope"]', "[]", '["opacity", "opacity"]', '["log_scales", "log_scale"]', "5"],
            "bits": ["[32]", "[-1]", "[true]", '"some"', "[]"],
            "samples": ["0", "-1", "1.5", "{margin = 2}", "{margin = 0.1, bogus = 1}", "true"],
            "sampling": ['"bogus"', "5"],
            "defenses": ['["nope"]', '["none", "none"]', "[]", '"none"'],
            "regions": ["[1]", "[65]", "[true]", "5"],
            "bogus": ["1"],
        }
        for key, vals in single.items():
            for v in vals:
                self.plan_case(f"single.{key} = {v}", spec_text(single=table("single", SINGLE, **{key: v})), "error")
        self.plan_case(
            "single bit 16 at fp16",
            spec_text(single='[single]\nprecisions = ["fp16"]\nbits = [16]\nsamples = 1\n'),
            "error",
        )
        for t in (
            '[single]\nfields = "all"\nbits = [0, 31]\nsamples = 1\n',
            '[single]\nsamples = {margin = 0.3}\nfields = ["opacity"]\nbits = [1]\n',
            '[single]\nfields = ["opacity"]\nbits = [30, 30]\nsamples = 1\n',
        ):
            self.plan_case(f"single ok: {t.splitlines()[1]}", spec_text(single=t), "ok")
        dose = [
            "k = []",
            "k = [0]",
            "k = [-1]",
            "k = [1.5]",
            "k = [true]",
            "k = [1]\nk_max = 10",
            "k_max = 0",
            "points = 0",
            "points = 201",
            "repeats = 0",
            'k = [1]\ndefenses = ["guard", "guard"]',
            "k = [100000000]",
            "bogus = 1",
        ]
        for d in dose:
            self.plan_case(f"dose {d}".replace("\n", "; "), spec_text(single="", extra=f"[dose]\n{d}\n"), "error")
        self.plan_case("dose ok", spec_text(single="", extra="[dose]\nk = [1, 2, 2]\nrepeats = 1\n"), "ok")
        sizes = ["n = []", "n = [0]", "n = [1.5]", 'n = ["x"]', "n = [10]\nbogus = 1"]
        for z in sizes:
            self.plan_case(f"sizes {z}".replace("\n", "; "), spec_text(single="", extra=f"[sizes]\n{z}\n"), "error")
        self.plan_case(  # a model file is cut to seeded subsets (Model.sample), not above its count
            "sizes on a model file",
            spec_text(scene='model = "good.ply"\n', single="", extra="[sizes]\nn = [10]\n"),
            "ok",
        )
        self.plan_case(
            "sizes above a model file's count",
            spec_text(scene='model = "good.ply"\n', single="", extra="[sizes]\nn = [10000000]\n"),
            "error",
        )
        self.plan_case("not TOML", "[[scenes\n", "error")
        self.add("spec", "spec is a folder", ["plan", self.work / "dir"])
        self.add("spec", "spec missing", ["plan", self.work / "nope.toml"])
        self.add("spec", "spec binary", ["plan", self.work / "good.ply"])
        self.add("spec", "spec empty", ["plan", self.work / "empty"])

    def plan_case(self, name, text, expect):
        p = self.fresh("spec").with_suffix(".toml")
        p.write_text(text)
        check = None
        if expect == "ok":

            def check(out):
                assert "total:" in out

        self.add("spec", name, ["plan", p], expect, check)

    def camera_cases(self):
        good = {
            "viewmat": scene_cameras("spheres", 1, 16, 16)[0].viewmat.tolist(),
            "K": [[20, 0, 8], [0, 20, 8], [0, 0, 1]],
        }
        good.update(width=16, height=16)
        bad = {
            "nan viewmat": {"viewmat": [[float("nan")] * 4] * 4},
            "inf K": {"K": [[float("inf"), 0, 8], [0, 20, 8], [0, 0, 1]]},
            "singular": {"viewmat": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 4], [0, 0, 0, 1]]},
            "mirrored": {"viewmat": [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]},
            "fx 0": {"K": [[0, 0, 8], [0, 20, 8], [0, 0, 1]]},
            "fy negative": {"K": [[20, 0, 8], [0, -20, 8], [0, 0, 1]]},
            "width 12.5": {"width": 12.5},
            "width true": {"width": True},
            "width null": {"width": None},
            "width 0": {"width": 0},
            "height -16": {"height": -16},
            "width text": {"width": "16"},
            "viewmat 3x3": {"viewmat": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
            "viewmat text": {"viewmat": "eye"},
            "K booleans": {"K": [[True, 0, 8], [0, 20, 8], [0, 0, 1]]},
            "last row": {"viewmat": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 1, 1]]},
        }
        for name, change in bad.items():
            p = self.fresh("cams").with_suffix(".json")
            p.write_text(json.dumps({"cameras": [dict(good, **change)]}))
            self.render_case("cameras", name, ["--cameras", p], "error")
        for name, text in {
            '{"cameras": 5}': '{"cameras": 5}',
            '{"cameras": []}': '{"cameras": []}',
            "not JSON": "{",
            "a list of numbers": "[1, 2]",
            "camera lacks K": json.dumps({"cameras": [{k: v for k, v in good.items() if k != "K"}]}),
            "frames = 5": '{"frames": 5}',
            "frame w null": json.dumps(
                {"fl_x": 20, "w": None, "h": 16, "frames": [{"transform_matrix": np.eye(4).tolist()}]}
            ),
            "frame fl_x text": json.dumps(
                {"fl_x": "x", "w": 16, "h": 16, "frames": [{"transform_matrix": np.eye(4).tolist()}]}
            ),
            "inria width null": json.dumps(
                [
                    {
                        "width": None,
                        "height": 16,
                        "position": [0, 0, 4],
                        "rotation": np.eye(3).tolist(),
                        "fx": 20,
                        "fy": 20,
                    }
                ]
            ),
            "inria fx bool": json.dumps(
                [
                    {
                        "width": 16,
                        "height": 16,
                        "position": [0, 0, 4],
                        "rotation": np.eye(3).tolist(),
                        "fx": True,
                        "fy": 20,
                    }
                ]
            ),
        }.items():
            p = self.fresh("cams").with_suffix(".json")
            p.write_text(text)
            self.render_case("cameras", name, ["--cameras", p], "error")
        self.render_case("cameras", "cameras missing", ["--cameras", self.work / "nope.json"], "error")
        self.render_case("cameras", "cameras folder without cameras", ["--cameras", self.work / "dir"], "error")
        self.render_case("cameras", "cameras binary", ["--cameras", self.work / "good.ply"], "error")
        p = self.fresh("cams").with_suffix(".json")
        p.write_text(json.dumps({"cameras": [good, good]}))
        self.render_case("cameras", "valid CAMS.json", ["--cameras", p], "ok", (2, 16, 16, 3))

    def render_case(self, category, name, extra, expect, shape=None, model=None):
        out = self.fresh("render").with_suffix(".npz")
        src = ["--model", model] if model is not None else ["--scene", "spheres", "--n", "80"]
        check = self.npz_shape(out, shape) if expect == "ok" else None
        self.add(category, name, ["render", *src, *extra, "--out", out], expect, check)

    def model_cases(self):
        g = self.good_ply
        head, body = g.split(b"end_header\n", 1)
        nan_model = make_scene("spheres", n=10, seed=2)
        nan_model.means[:] = np.nan
        save_model(nan_model, self.work / "allnan.ply")
        part = make_scene("spheres", n=10, seed=2)
        part.means[3] = np.nan
        save_model(part, self.work / "somenan.ply")
        variants = {
            "empty file": b"",
            "garbage": b"\x00\x01garbage" * 10,
            "header only": head + b"end_header\n",
            "truncated header": head[: len(head) // 2],
            "truncated data": head + b"end_header\n" + body[: len(body) // 2],
            "one byte short": g[:-1],
            "header count below data": g.replace(b"element vertex 80\n", b"element vertex 60\n"),
            "header count above data": g.replace(b"element vertex 80\n", b"element vertex 99\n"),
            "zero vertices": g.replace(b"element vertex 80\n", b"element vertex 0\n"),
            "negative count": g.replace(b"element vertex 80\n", b"element vertex -5\n"),
            "unknown format": g.replace(b"binary_little_endian", b"binary_middle_endian"),
            "missing opacity": g.replace(b"property float opacity\n", b""),
            "property twice": g.replace(
                b"property float opacity\n", b"property float opacity\nproperty float opacity\n"
            ),
            "unknown type": g.replace(b"property float opacity\n", b"property quad opacity\n"),
            "non-UTF-8 header": g.replace(b"format", b"\xff\xfeformat", 1),
            "spz truncated": (self.work / "good.spz").read_bytes()[:40],
            "spz garbage after magic": b"\x1f\x8b\x08\x00" + b"\x00" * 50,
            "splat odd size": b"\x00" * 33,
            "torch magic": b"PK\x03\x04" + b"\x00" * 60,
            "ascii malformed": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\nabc\n",
        }
        for name, data in variants.items():
            p = self.fresh("model").with_suffix(".ply" if "spz" not in name else ".spz")
            p.write_bytes(data)
            self.render_case("model", name, ["--views", "1", "--size", "16x16"], "error", model=p)
        self.render_case(
            "model", "all-NaN model", ["--views", "1", "--size", "16x16"], "error", model=self.work / "allnan.ply"
        )
        self.render_case(
            "model", "model missing", ["--views", "1", "--size", "16x16"], "error", model=self.work / "nope.ply"
        )
        self.render_case(
            "model", "model is a folder", ["--views", "1", "--size", "16x16"], "error", model=self.work / "dir"
        )
        for name, p in (("valid PLY", "good.ply"), ("valid SPZ", "good.spz"), ("one NaN primitive", "somenan.ply")):
            self.render_case("model", name, ["--views", "1", "--size", "16x16"], "ok", (1, 16, 16, 3), self.work / p)

    # ---- .ksplat and SOG files, made from the committed fixtures --------------------------------
    def format_files(self):
        """The fixtures in the work folder, and what render/inject/campaign cases compare with:
        each one's render next to that of splat-transform's decode of it (X.ref.ply)."""
        w = self.work
        for name in ("level0_sh2.ksplat", "level1_sh1.ksplat", "level2_sh2.ksplat", "sh3.sog", "sog_meta"):
            src = FIXTURES / name
            if src.is_dir():
                shutil.copytree(src, w / name)
            else:
                shutil.copy(src, w / name)
            shutil.copy(FIXTURES / f"{name}.ref.ply", w / f"{name}.ref.ply")
        self.ksplat = {lvl: (FIXTURES / f"level{lvl}_sh{deg}.ksplat").read_bytes() for lvl, deg in enumerate((2, 1, 2))}
        with zipfile.ZipFile(FIXTURES / "sh3.sog") as z:
            self.sog_members = {n: z.read(n) for n in z.namelist()}
        self.sog_meta = json.loads(self.sog_members["meta.json"])

    def sog_zip(self, change=None, drop=(), replace=None) -> bytes:
        """sh3.sog with meta.json changed (`change(meta)`), members dropped or replaced."""
        meta = json.loads(json.dumps(self.sog_meta))
        if change is not None:
            change(meta)
        members = {**self.sog_members, "meta.json": json.dumps(meta).encode(), **(replace or {})}
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            for name, data in members.items():
                if name not in drop:
                    z.writestr(name, data)
        return buf.getvalue()

    def sog_folder(self, change=None, drop=(), replace=None, meta_bytes=None) -> Path:
        """A copy of the unbundled fixture sog_meta/ with meta.json changed, images dropped or replaced."""
        d = self.fresh("sogdir")
        shutil.copytree(FIXTURES / "sog_meta", d)
        if change is not None:
            meta = json.loads((d / "meta.json").read_text())
            change(meta)
            (d / "meta.json").write_text(json.dumps(meta))
        if meta_bytes is not None:
            (d / "meta.json").write_bytes(meta_bytes)
        for name in drop:
            (d / name).unlink()
        for name, data in (replace or {}).items():
            (d / name).write_bytes(data)
        return d

    def format_render(self, name, model, expect="ok", views=None):
        """A render of `model` with the battery's two 16x16 cameras (or framed by the model:
        `views`), checked for its size and finite pixels."""
        extra = ["--views", str(views), "--size", "16x16"] if views else ["--cameras", self.work / "cams.json"]
        self.render_case("model", name, extra, expect, ((views or 2), 16, 16, 3), model)

    def format_cases(self):
        w = self.work
        cams = ["--cameras", w / "cams.json"]
        # the valid fixtures: each render matches the render of splat-transform's decode of it
        for name in ("level0_sh2.ksplat", "level1_sh1.ksplat", "level2_sh2.ksplat", "sh3.sog", "sog_meta"):
            ref = self.fresh("render").with_suffix(".npz")
            self.add(
                "model",
                f"{name}.ref.ply (splat-transform's decode)",
                ["render", "--model", w / f"{name}.ref.ply", *cams, "--out", ref],
                "ok",
                self.npz_shape(ref, (2, 16, 16, 3)),
            )
            out = self.fresh("render").with_suffix(".npz")
            self.add(
                "model",
                f"valid {name}, like its decode by splat-transform",
                ["render", "--model", w / name, *cams, "--out", out],
                "ok",
                self.npz_like(out, ref, (2, 16, 16, 3)),
            )
        self.format_render("valid sog_meta/meta.json", w / "sog_meta" / "meta.json")
        self.format_render("valid sog_meta framed by the model", w / "sog_meta", views=1)
        self.format_render("valid sh3.sog framed by the model", w / "sh3.sog", views=1)
        self.format_render("valid level1_sh1.ksplat framed by the model", w / "level1_sh1.ksplat", views=1)
        for name, src in (("ksplat named .bin", "level2_sh2.ksplat"), ("sog named .zip", "sh3.sog")):
            p = self.fresh("model").with_suffix(".zip" if "zip" in name else ".bin")
            shutil.copy(FIXTURES / src, p)
            self.format_render(f"valid {name} (recognised by content)", p)
        d = self.sog_folder()
        (d / "meta.json").rename(d / "scene.json")
        self.format_render("valid unbundled SOG as scene.json", d / "scene.json")
        self.ksplat_cases()
        self.sog_cases()
        # inject and campaigns on the valid fixtures
        for name in ("sh3.sog", "sog_meta", "level2_sh2.ksplat"):
            out = self.fresh("inj")
            argv = ["inject", "--model", w / name, "--views", "1", "--size", "16x16", "--field", "opacity"]
            self.add(
                "model",
                f"inject into {name}",
                [*argv, "--primitive", "3", "--bit", "30", "--out", out],
                "ok",
                self.bit_flipped(out, 30),
            )
        for name, label in (
            ("sh3.sog", "sh3"),
            ("sog_meta", "sog_meta"),
            ("sog_meta/meta.json", "sog_meta"),
            ("level1_sh1.ksplat", "level1_sh1"),
        ):
            spec = self.fresh("spec").with_suffix(".toml")
            spec.write_text(spec_text(scene=f'model = "{name}"\n'))
            out = self.fresh("run")
            self.add(
                "model",
                f'campaign on model = "{name}"',
                ["campaign", spec, "--out", out, "--quiet"],
                "ok",
                self.records_of(out, 2, label),
            )
        for name, data in (
            ("cut.ksplat", self.ksplat[2][:-100]),
            ("noimage.sog", self.sog_zip(drop=("quats.webp",))),
            ("v3.sog", self.sog_zip(lambda m: m.update(version=3))),
        ):
            (w / name).write_bytes(data)
            spec = self.fresh("spec").with_suffix(".toml")
            spec.write_text(spec_text(scene=f'model = "{name}"\n'))
            self.add(
                "model", f'campaign on model = "{name}"', ["campaign", spec, "--out", self.fresh("run"), "--quiet"]
            )

    def ksplat_cases(self):
        k0, k1, k2 = self.ksplat[0], self.ksplat[1], self.ksplat[2]
        sec = 4096  # the first section header

        def put(data, *edits):
            b = bytearray(data)
            for offset, fmt, value in edits:
                struct.pack_into(fmt, b, offset, value)
            return bytes(b)

        bad = {
            "empty .ksplat": b"",
            "cut to 100 bytes": k2[:100],
            "cut to 4095 bytes": k2[:4095],
            "cut to its main header": k2[:4096],
            "cut in its section header": k2[: sec + 512],
            "cut after its headers": k2[: sec + 1024],
            "cut in its bucket table": k2[: sec + 1024 + 60],
            "cut mid-records": k2[: len(k2) // 2 + 7],
            "one byte short": k2[:-1],
            "level 0, one byte short": k0[:-1],
            "a byte past its end": k2 + b"\0",
            "4096 zeros past its end": k1 + bytes(4096),
            "version 1.1": put(k2, (0, "B", 1)),
            "version 0.0": put(k2, (1, "B", 0)),
            "compression level 3": put(k2, (20, "<H", 3)),
            "compression level 65535": put(k2, (20, "<H", 65535)),
            "level 0 marked level 1": put(k0, (20, "<H", 1)),
            "level 2 marked level 1": put(k2, (20, "<H", 1)),
            "level 1 marked level 0": put(k1, (20, "<H", 0)),
            "0 sections": put(k2, (4, "<I", 0)),
            "2 sections": put(k2, (4, "<I", 2)),
            "2**32-1 sections": put(k2, (4, "<I", 2**32 - 1)),
            "header counts 300 splats": put(k2, (16, "<I", 300)),
            "header counts 0 splats": put(k2, (16, "<I", 0)),
            "header counts 2**32-1 splats": put(k2, (16, "<I", 2**32 - 1)),
            "0 splats in header and section": put(k2, (16, "<I", 0), (sec, "<I", 0)),
            "a section over its capacity": put(k2, (16, "<I", 257), (sec, "<I", 257)),
            "section capacity 255": put(k2, (sec + 4, "<I", 255)),
            "section capacity 2**32-1": put(k2, (sec + 4, "<I", 2**32 - 1)),
            "2**32-1 buckets": put(k2, (sec + 12, "<I", 2**32 - 1)),
            "24 buckets of 25": put(k2, (sec + 12, "<I", 24)),
            "8-byte buckets": put(k1, (sec + 20, "<H", 8)),
            "0-byte buckets": put(k2, (sec + 20, "<H", 0)),
            "no full buckets": put(k2, (sec + 32, "<I", 0)),
            "2**32-1 partial buckets": put(k2, (sec + 36, "<I", 2**32 - 1)),
            "bucket size 0": put(k1, (sec + 8, "<I", 0)),
            "SH degree 3": put(k2, (sec + 40, "<H", 3)),
            "SH degree 65535": put(k2, (sec + 40, "<H", 65535)),
            "SH degree 1 in a degree-2 file": put(k2, (sec + 40, "<H", 1)),
            "SH degree 2 in a degree-1 file": put(k1, (sec + 40, "<H", 2)),
            "bucket block NaN": put(k1, (sec + 16, "<f", float("nan"))),
            "bucket block inf": put(k2, (sec + 16, "<f", float("inf"))),
        }
        for name, data in bad.items():
            p = self.fresh("model").with_suffix(".ksplat")
            p.write_bytes(data)
            self.format_render(f"ksplat {name}", p, "error")
        p = self.fresh("model").with_suffix(".bin")
        p.write_bytes(k2[:-1])
        self.format_render("ksplat one byte short, named .bin", p, "error")
        good = {  # consistent files: read as they say
            "255 of its 256 splats": put(k2, (16, "<I", 255), (sec, "<I", 255)),
            "position range 1": put(k1, (sec + 24, "<I", 1)),
            "bucket block 1e30": put(k1, (sec + 16, "<f", 1e30)),
            "SH range NaN": put(k2, (36, "<f", float("nan")), (40, "<f", float("nan"))),
            "SH range +-1e30": put(k2, (36, "<f", -1e30), (40, "<f", 1e30)),
            "unused section count 9": put(k2, (8, "<I", 9)),
        }
        for name, data in good.items():
            p = self.fresh("model").with_suffix(".ksplat")
            p.write_bytes(data)
            self.format_render(f"ksplat {name}", p, "ok", views=1)

    def sog_cases(self):
        w = self.work
        whole = (FIXTURES / "sh3.sog").read_bytes()
        png = io.BytesIO()
        Image.fromarray(np.zeros((16, 16, 4), np.uint8)).save(png, "PNG")
        small = io.BytesIO()
        Image.fromarray(np.zeros((8, 8, 4), np.uint8)).save(small, "WEBP", lossless=True)
        centroids = self.sog_members["shN_centroids.webp"]
        bomb = webp_claiming(16383, 16383)  # 268 M pixels: Pillow's decompression-bomb limit
        large = webp_claiming(12000, 9000)  # 108 M pixels: under it, but no image data behind

        def at(key, **values):
            return lambda meta: meta[key].update(values)

        def top(**values):
            return lambda meta: meta.update(values)

        def pop(*path):
            def change(meta):
                d = meta
                for k in path[:-1]:
                    d = d[k]
                d.pop(path[-1])

            return change

        nan_entry = lambda meta: meta["scales"]["codebook"].__setitem__(5, float("nan"))  # noqa: E731
        bad_zip = {
            "empty .sog": b"",
            "a .sog that is text": b"not a zip, not a model\n",
            "a .sog that is JSON": json.dumps(self.sog_meta).encode(),
            "cut to 100 bytes": whole[:100],
            "cut in half": whole[: len(whole) // 2],
            "cut before its directory's end": whole[:-22],
            "one byte short": whole[:-1],
            "an empty zip": self.sog_zip(drop=tuple(self.sog_members)),
            "a zip without meta.json": self.sog_zip(drop=("meta.json",)),
            "meta.json not JSON": self.sog_zip(replace={"meta.json": b"{not json"}),
            "meta.json a list": self.sog_zip(replace={"meta.json": b"[1, 2]"}),
            "meta.json not UTF-8": self.sog_zip(replace={"meta.json": b'{"version": 2, "\xff": 1}'}),
            "meta.json without version": self.sog_zip(pop("version")),
            "version 3": self.sog_zip(top(version=3)),
            'version "2"': self.sog_zip(top(version="2")),
            "version true": self.sog_zip(top(version=True)),
            "version null": self.sog_zip(top(version=None)),
            "count 0": self.sog_zip(top(count=0)),
            "count -1": self.sog_zip(top(count=-1)),
            "count 257, above its images": self.sog_zip(top(count=257)),
            "count 2**40": self.sog_zip(top(count=2**40)),
            'count "256"': self.sog_zip(top(count="256")),
            "count 256.5": self.sog_zip(top(count=256.5)),
            "count missing": self.sog_zip(pop("count")),
            "means.mins NaN": self.sog_zip(at("means", mins=[float("nan")] * 3)),
            "means.maxs Infinity": self.sog_zip(at("means", maxs=[float("inf")] * 3)),
            "means.mins -1e308, maxs 1e308": self.sog_zip(at("means", mins=[-1e308] * 3, maxs=[1e308] * 3)),
            "means.mins 2 numbers": self.sog_zip(at("means", mins=[0.0, 0.0])),
            "means.mins text": self.sog_zip(at("means", mins=["a", "b", "c"])),
            "means.maxs missing": self.sog_zip(pop("means", "maxs")),
            "means lists one image": self.sog_zip(at("means", files=["means_l.webp"])),
            "means.files not a list": self.sog_zip(at("means", files="means_l.webp")),
            "an image named 5": self.sog_zip(at("quats", files=[5])),
            "quats missing": self.sog_zip(pop("quats")),
            "scales codebook of 255": self.sog_zip(at("scales", codebook=[0.0] * 255)),
            "scales codebook all NaN": self.sog_zip(at("scales", codebook=[float("nan")] * 256)),
            "sh0 codebook of text": self.sog_zip(at("sh0", codebook=["x"] * 256)),
            "shN.bands 4": self.sog_zip(at("shN", bands=4)),
            'shN.bands "3"': self.sog_zip(at("shN", bands="3")),
            "shN.bands true": self.sog_zip(at("shN", bands=True)),
            "shN.count 0": self.sog_zip(at("shN", count=0)),
            "shN.count 3, below its labels": self.sog_zip(at("shN", count=3)),
            "shN.bands 2 for degree-3 centroids": self.sog_zip(at("shN", bands=2)),
            "shN without files": self.sog_zip(pop("shN", "files")),
            "an image missing": self.sog_zip(drop=("quats.webp",)),
            "an image of 0 bytes": self.sog_zip(replace={"sh0.webp": b""}),
            "an image of garbage": self.sog_zip(replace={"scales.webp": b"RIFF\x10\0\0\0WEBPgarbage!"}),
            "a PNG where a WebP belongs": self.sog_zip(replace={"quats.webp": png.getvalue()}),
            "an image of 8 x 8 texels": self.sog_zip(replace={"means_u.webp": small.getvalue()}),
            "centroids as labels": self.sog_zip(replace={"shN_labels.webp": centroids}),
            "an image cut in half": self.sog_zip(replace={"shN_centroids.webp": centroids[: len(centroids) // 2]}),
            "an image claiming 16383 x 16383 texels": self.sog_zip(replace={"sh0.webp": bomb}),
            "an image claiming 12000 x 9000 texels": self.sog_zip(replace={"sh0.webp": large}),
            "a member's CRC broken": crc_broken(self.sog_zip(), "quats.webp"),
        }
        for name, data in bad_zip.items():
            p = self.fresh("model").with_suffix(".sog")
            p.write_bytes(data)
            self.format_render(f"sog {name}", p, "error")
        good_zip = {  # read as they say
            "count 100, below its images": self.sog_zip(top(count=100)),
            "version 2.0": self.sog_zip(top(version=2.0)),
            "mins above maxs": self.sog_zip(
                at("means", mins=self.sog_meta["means"]["maxs"], maxs=self.sog_meta["means"]["mins"])
            ),
            "mins equal to maxs": self.sog_zip(at("means", mins=[0.1] * 3, maxs=[0.1] * 3)),
            "maxs 60 (positions near 1e26)": self.sog_zip(at("means", maxs=[60.0] * 3)),
            "one NaN scales codebook entry": self.sog_zip(nan_entry),
            "shN.bands 0": self.sog_zip(at("shN", bands=0)),
            "no shN": self.sog_zip(pop("shN")),
            'model "2dgs"': self.sog_zip(top(model="2dgs")),
            'model "bogus"': self.sog_zip(top(model="bogus")),
            "meta.json with a BOM": self.sog_zip(
                replace={"meta.json": b"\xef\xbb\xbf" + self.sog_members["meta.json"]}
            ),
            "an extra member": self.sog_zip(replace={"readme.txt": b"hello"}),
        }
        for name, data in good_zip.items():
            p = self.fresh("model").with_suffix(".sog")
            p.write_bytes(data)
            self.format_render(f"sog {name}", p, "ok", views=1)
        images = [n for n in os.listdir(FIXTURES / "sog_meta") if n.endswith(".webp")]
        folders = {
            "a folder with meta.json, no images": self.sog_folder(drop=images),
            "a folder without sh0.webp": self.sog_folder(drop=("sh0.webp",)),
            "a folder whose meta.json is empty": self.sog_folder(meta_bytes=b""),
            'a folder whose meta.json is {"a": 1}': self.sog_folder(meta_bytes=b'{"a": 1}'),
            "a folder, image named ../good.ply": self.sog_folder(at("quats", files=["../good.ply"])),
            "a folder, image named .": self.sog_folder(at("quats", files=["."])),
            "a folder, an image of garbage": self.sog_folder(replace={"quats.webp": b"garbage"}),
            "a folder, labels of 8 x 8 texels": self.sog_folder(replace={"shN_labels.webp": small.getvalue()}),
            "a folder, count 257": self.sog_folder(top(count=257)),
            "a folder, means.maxs NaN": self.sog_folder(at("means", maxs=[float("nan")] * 3)),
        }
        for name, d in folders.items():
            self.format_render(f"sog {name}", d, "error")
        d = self.sog_folder(drop=("sh0.webp",))
        self.format_render("sog meta.json of a folder without sh0.webp", d / "meta.json", "error")
        d = self.fresh("sogdir")
        (d / "meta.json").mkdir(parents=True)
        self.format_render("sog a folder whose meta.json is a folder", d, "error")
        self.format_render("sog a folder with nothing", w / "dir", "error")

    def argument_cases(self):
        bad = {
            "--n 0": ["--n", "0"],
            "--n -5": ["--n", "-5"],
            "--n abc": ["--n", "abc"],
            "--views 0": ["--views", "0"],
            "--size 0x0": ["--size", "0x0"],
            "--size 10x": ["--size", "10x"],
            "--scale 0": ["--scale", "0"],
            "--scale -1": ["--scale", "-1"],
            "--scale nan": ["--scale", "nan"],
            "--scale inf": ["--scale", "inf"],
            "--precision fp64": ["--precision", "fp64"],
            "--up q": ["--up", "q"],
            "--sh-degree 4": ["--sh-degree", "4"],
            "--scene nope": ["--scene", "nope"],
        }
        for name, extra in bad.items():
            argv = ["render", "--scene", "spheres", "--n", "50", *extra, "--out", self.fresh("o").with_suffix(".npz")]
            if extra[0] == "--scene":
                argv = ["render", *extra, "--out", self.fresh("o").with_suffix(".npz")]
            self.add("arguments", name, argv)
        self.add(
            "arguments", "render --out under a file", ["render", "--n", "50", "--out", self.work / "file" / "x.npz"]
        )
        self.add("arguments", "render --out in /proc", ["render", "--n", "50", "--out", "/proc/seuwgpu/x.npz"])
        inj = ["inject", "--scene", "spheres", "--n", "60", "--views", "1", "--size", "16x16"]
        for name, extra in {
            "inject --sample 0": ["--field", "opacity", "--bit", "3", "--sample", "0"],
            "inject --primitive -1": ["--field", "opacity", "--bit", "3", "--primitive", "-1"],
            "inject --primitive 60": ["--field", "opacity", "--bit", "3", "--primitive", "60"],
            "inject --component 9": ["--field", "opacity", "--bit", "3", "--primitive", "1", "--component", "9"],
            "inject --bit 32": ["--field", "opacity", "--bit", "32", "--primitive", "1"],
            "inject --bit 16 at fp16": ["--field", "opacity", "--bit", "16", "--primitive", "1", "--precision", "fp16"],
            "inject --field nope": ["--field", "nope", "--bit", "3", "--primitive", "1"],
            "inject --defense nope": ["--field", "opacity", "--bit", "3", "--defense", "nope"],
        }.items():
            self.add("arguments", name, [*inj, *extra, "--out", self.fresh("inj")])
        out = self.fresh("inj")

        def sign_flip(stdout):
            lines = dict(line.split(": ", 1) for line in stdout.splitlines() if ": " in line)
            assert float(lines["corrupted_value"]) == -float(lines["clean_value"]), lines
            assert (out / "panel.png").is_file()

        self.add(
            "arguments",
            "inject a sign flip",
            [*inj, "--field", "log_scales", "--primitive", "2", "--bit", "31", "--out", out],
            "ok",
            sign_flip,
        )
        spec = self.fresh("spec").with_suffix(".toml")
        spec.write_text(spec_text())
        for name, shard in {
            "--shard 2/2": "2/2",
            "--shard 0/0": "0/0",
            "--shard x": "x",
            "--shard -1/2": "-1/2",
        }.items():
            self.add("arguments", name, ["campaign", spec, "--out", self.fresh("run"), "--shard", shard])
        self.add("arguments", "campaign --workers 0", ["campaign", spec, "--out", self.fresh("run"), "--workers", "0"])
        self.add("arguments", "campaign --out is a file", ["campaign", spec, "--out", self.work / "file"])
        self.add("arguments", "campaign --out under a file", ["campaign", spec, "--out", self.work / "file" / "run"])
        self.add("arguments", "campaign --out in /proc", ["campaign", spec, "--out", "/proc/seuwgpu-run"])
        self.add("arguments", "report of a missing dir", ["report", self.work / "nope", "--out", self.fresh("rep")])
        self.add("arguments", "report of an empty dir", ["report", self.work / "dir", "--out", self.fresh("rep")])
        self.add("arguments", "rates of a missing dir", ["rates", self.work / "nope"])
        self.add("arguments", "rates of an empty dir", ["rates", self.work / "dir"])
        self.add("arguments", "rates --by typo", ["rates", self.work / "dir", "--by", "precison"])
        self.add("arguments", "scene without --out", ["scene", "spheres", "--n", "10"])
        self.add(
            "arguments",
            "scene to .obj",
            ["scene", "spheres", "--n", "10", "--out", self.fresh("s").with_suffix(".obj")],
        )
        self.add("arguments", "plan --margin 2", ["plan", spec, "--margin", "2"])
        self.add("arguments", "plan --confidence 0", ["plan", spec, "--confidence", "0"])
        self.add("arguments", "distributed --ranks 0", ["distributed", "--n", "50", "--ranks", "0"])
        self.add("arguments", "distributed --upset bad", ["distributed", "--n", "50", "--upset", "nope"])
        self.add("arguments", "view --sample 0", ["view", "--n", "50", "--sample", "0"])
        small = ["--scene", "spheres", "--n", "50", "--views", "1", "--size", "16x16"]
        self.add("arguments", "state --bit 32", ["state", *small, "--bit", "32", "--out", self.fresh("st")])
        self.add("arguments", "state --bit -1", ["state", *small, "--bit", "-1", "--out", self.fresh("st")])
        self.add("arguments", "worstcase --bit 32", ["worstcase", *small, "--bit", "32", "--fields", "opacity"])
        self.add(
            "arguments",
            "worstcase --bit 16 at fp16",
            ["worstcase", *small, "--precision", "fp16", "--bit", "16", "--fields", "opacity"],
        )
        self.add("arguments", "no command", [])
        self.add("arguments", "unknown command", ["frobnicate"])

    def run_dir_cases(self):
        spec = self.work / "rd.toml"
        spec.write_text(spec_text(top={"batch": "2"}, single=table("single", SINGLE, samples="6")))  # 3 parts
        ref = self.work / "rd_ref"
        self.ref_spec, self.ref_dir = spec, ref
        self.add(
            "run directory",
            "reference run",
            ["campaign", spec, "--out", ref, "--quiet"],
            "ok",
            self.records_equal(ref, ref),
        )
        self.add(
            "run directory",
            "rates --by a column named twice",
            ["rates", ref, "--by", "scene,scene"],
            "ok",
            lambda out: self.assert_in("│ spheres │", out) or self.assert_not_in("dtype", out),
        )
        # same spec through another path: resumes with nothing new
        (self.work / "sub").mkdir(exist_ok=True)
        self.add(
            "run directory",
            "same spec by another path resumes",
            ["campaign", self.work / "sub" / ".." / "rd.toml", "--out", ref, "--quiet"],
            "ok",
            lambda out: self.assert_in("6 of 6 injections recorded (nothing new to run)", out),
        )
        other = self.work / "rd_other.toml"
        other.write_text(spec_text(top={"seed": "9"}))
        self.add("run directory", "another spec on the same --out", ["campaign", other, "--out", ref, "--quiet"])
        # a model changed between runs
        mspec = self.work / "rd_model.toml"
        shutil.copy(self.work / "good.ply", self.work / "changing.ply")
        mspec.write_text(spec_text(scene='model = "changing.ply"\n'))
        self.model_run = self.work / "rd_model"
        self.add("run directory", "run on a model file", ["campaign", mspec, "--out", self.model_run, "--quiet"], "ok")
        self.add(
            "run directory",
            "resume after the model changed",
            ["campaign", mspec, "--out", self.model_run, "--quiet"],
            "error",
            before=lambda: save_model(make_scene("spheres", n=80, seed=5), self.work / "changing.ply"),
        )
        # a failed validation does not block the corrected spec
        bad = self.work / "rd_bad.toml"
        (self.work / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n")
        bad.write_text(spec_text(scene='model = "bad.ply"\n'))
        fixed_out = self.work / "rd_fixed"
        self.add("run directory", "a spec whose model fails to load", ["campaign", bad, "--out", fixed_out, "--quiet"])
        self.add(
            "run directory",
            "the corrected spec on the same --out",
            ["campaign", spec, "--out", fixed_out, "--quiet"],
            "ok",
            self.records_equal(fixed_out, ref),
        )
        # damaged and stray parts
        for name, damage in {
            "a 0-byte part": lambda d: store.part_files(d)[0].write_bytes(b""),
            "an unreadable part": lambda d: store.part_files(d)[0].write_bytes(b"PAR1xx"),
            "a stray part": lambda d: shutil.copy(store.part_files(d)[0], store.part_path(d, 999_999, 2)),
            "a deleted part": lambda d: store.part_files(d)[0].unlink(),
            "a part of another batch": lambda d: shutil.copy(store.part_files(d)[0], store.part_path(d, 0, 5)),
        }.items():
            d = self.fresh("rd_damaged")

            def prepare(d=d, damage=damage):
                shutil.copytree(ref, d)
                damage(d)

            self.add(
                "run directory",
                f"resume over {name}",
                ["campaign", spec, "--out", d, "--quiet"],
                "ok",
                self.records_equal(d, ref),
                before=prepare,
            )
        d = self.fresh("rd_manifest")

        def garble(d=d):
            shutil.copytree(ref, d)
            (d / "manifest.json").write_text("{not json")

        self.add("run directory", "an unreadable manifest", ["campaign", spec, "--out", d, "--quiet"], before=garble)
        # merges
        shards = [self.work / f"rd_shard{i}" for i in range(3)]
        for i, s in enumerate(shards):
            self.add("merge", f"shard {i}/3", ["campaign", spec, "--out", s, "--shard", f"{i}/3", "--quiet"], "ok")
        self.add("merge", "2 of 3 shards", ["merge", *shards[:2], "--out", self.fresh("merged")])
        partial = self.fresh("merged")

        def lists_missing(_out):
            m = store.read_manifest(partial)
            assert m["missing_parts"] and m["injections_recorded"] < m["total_injections"], m

        self.add(
            "merge",
            "2 of 3 shards, --allow-partial",
            ["merge", *shards[:2], "--out", partial, "--allow-partial"],
            "ok",
            lists_missing,
        )
        full = self.fresh("merged")
        self.add("merge", "all shards", ["merge", *shards, "--out", full], "ok", self.records_equal(full, ref))
        both = self.fresh("merged")  # the parts of a whole run and of its shards: the same records, timed anew
        self.add(
            "merge",
            "a whole run beside its shards",
            ["merge", ref, *shards, "--out", both],
            "ok",
            self.records_equal(both, ref),
        )
        self.add("merge", "--out is an input", ["merge", *shards, "--out", shards[0]])
        self.add("merge", "shards of two specs", ["merge", shards[0], self.model_run, "--out", self.fresh("merged")])
        self.add("merge", "into a run of another spec", ["merge", *shards, "--out", self.model_run])
        self.add("merge", "a folder that is no run", ["merge", self.work / "dir", "--out", self.fresh("merged")])
        self.add("merge", "a missing folder", ["merge", self.work / "nope", "--out", self.fresh("merged")])

    @staticmethod
    def assert_in(text, out):
        assert text in out, out

    @staticmethod
    def assert_not_in(text, out):
        assert text not in out, out

    @staticmethod
    def records_equal(run, ref):
        def check(_out):
            a, b = (
                store.read_records(d)
                .sort_values(["injection_id", "defense"])
                .reset_index(drop=True)[store.REPRODUCIBLE_COLUMNS]
                for d in (run, ref)
            )
            assert len(a) == len(b) and a.equals(b), (len(a), len(b))
            assert len(set(zip(a["injection_id"], a["defense"]))) == len(a), "duplicated records"

        return check

    def interruption_cases(self):
        spec = self.work / "kill.toml"
        spec.write_text(
            spec_text(
                single=table(
                    "single",
                    SINGLE,
                    fields='["opacity", "log_scales"]',
                    bits="[0, 30, 31]",
                    samples="12",
                    defenses='["none", "guard"]',
                )
            )
        )
        ref = self.work / "kill_ref"
        self.add(
            "interruption", "uninterrupted reference", ["campaign", spec, "--out", ref, "--quiet"], "ok", process=True
        )
        for i, delay in enumerate((0.0, 0.3, 0.6, 0.1, 0.45)):
            d = self.work / f"kill_{i}"
            self.add(
                "interruption",
                f"3 x SIGKILL {delay}s after a new part, resume",
                ["campaign", spec, "--out", d, "--quiet"],
                "ok",
                self.records_equal(d, ref),
                process=True,
                kill=(signal.SIGKILL, delay, 3),
            )
        # SIGTERM stops a run as Ctrl-C does: exit 143, the part in hand written whole. Both at
        # once after a part: 0.2 s after one, this small run had written all 18 and was ending
        for name, folder, kill in (
            ("SIGINT, then resume", "kill_int", (signal.SIGINT, 0.0, 1)),
            ("2 x SIGTERM, then resume", "kill_term", (signal.SIGTERM, 0.0, 2)),
        ):
            d = self.work / folder
            self.add(
                "interruption",
                name,
                ["campaign", spec, "--out", d, "--quiet"],
                "ok",
                self.records_equal(d, ref),
                process=True,
                kill=kill,
            )
        d = self.work / "busy"
        self.add(
            "interruption",
            "a second campaign while the first runs",
            ["campaign", spec, "--out", d, "--quiet"],
            "error",
            process=True,
            concurrent=True,
        )

    # ---- storm and state: partial records, resumed ----------------------------------------------
    STORM = ["--scene", "spheres", "--n", "50", "--size", "16x16", "--k", "2", "--frames", "600"]
    STATE = ["--scene", "spheres", "--n", "50", "--views", "1", "--size", "16x16", "--samples", "8"]

    @staticmethod
    def same_results(run, ref, name):
        """A storm's or state's records equal the uninterrupted reference run's, and no partial
        file is left."""

        def check(_out):
            import pandas as pd

            a, b = (pd.read_parquet(d / f"{name}.parquet") for d in (run, ref))
            assert len(a) == len(b) and a.equals(b), (len(a), len(b))
            assert not (run / f"{name}.partial.parquet").exists(), "the partial file was left"

        return check

    def interrupted(self, name: str, argv: list, d: Path):
        """`before` of a case: d holds an interrupted run of argv (SIGINT after it has measured a
        while), made once per command and copied."""
        master = self.work / f"{name}_interrupted"

        def prepare():
            if not master.exists():
                interrupt_once(Case("", "", [*argv, "--out", master], kill=(signal.SIGINT, 4.0, 1), kill_after="lock"))
            partial = master / f"{name}.partial.parquet"
            assert partial.exists(), f"no interrupted {name} run to start from (SIGINT 4 s after its lock)"
            shutil.copytree(master, d)

        return prepare

    def add_resumed(self, category: str, name: str, argv: list, d: Path, **kw):
        """A storm or state case in a process, on --out d: it must end well with the records of
        the uninterrupted reference run of its command (work/COMMAND_ref)."""
        command = str(argv[0])
        ref = self.work / f"{command}_ref"
        check = self.same_results(d, ref, command)
        needs = f"{command}: uninterrupted reference"
        self.add(category, name, [*argv, "--out", d], "ok", check, process=True, needs=needs, **kw)

    def partial_run_cases(self):
        garbage, older = lambda p: p.write_bytes(b"PAR1 not a parquet file"), strip_run_meta
        empty, halved = lambda p: p.write_bytes(b""), lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
        for name, args, other, damages in (  # other arguments, damaged partial files (two each, for time)
            (
                "storm",
                [*self.STORM, "--defense", "none", "guard"],
                {"--k 3": ["--k", "3"], "--seed 9": ["--seed", "9"]},
                {"garbage": garbage, "no run arguments (an older seuwgpu's)": older},
            ),
            (
                "state",
                self.STATE,
                {"--samples 9": ["--samples", "9"], "--targets xy": ["--targets", "xy"]},
                {"a 0-byte file": empty, "half of it": halved},
            ),
        ):
            argv = [name, *args]
            ref = self.work / f"{name}_ref"
            self.add(
                "interruption",
                f"{name}: uninterrupted reference",
                [*argv, "--out", ref],
                "ok",
                self.file_exists(ref / f"{name}.parquet"),
                process=True,
            )
            for sig, delay, times, after in (
                # the lock is taken before the engine starts (about 2 s here): measuring starts later
                (signal.SIGINT, 4.0, 1, "lock"),
                (signal.SIGTERM, 3.5, 2, "lock"),
                (signal.SIGKILL, 0.3, 1, "save"),
            ):
                d = self.fresh(f"{name}_kill")
                when = "after a periodic save" if after == "save" else "mid-run"
                self.add_resumed(
                    "interruption",
                    f"{name}: {times} x {signal.Signals(sig).name} {when}, then resume",
                    argv,
                    d,
                    kill=(sig, delay, times),
                    kill_after=after,
                )
            d = self.fresh(f"{name}_busy")
            self.add(
                "interruption",
                f"{name}: a second run while the first runs",
                [*argv, "--out", d],
                "error",
                process=True,
                concurrent=True,
            )
            for what, extra in other.items():
                d = self.fresh(f"{name}_other")
                self.add(
                    "run directory",
                    f"{name}: resume with {what}",
                    [*argv, *extra, "--out", d],
                    before=self.interrupted(name, argv, d),
                )
            for what, damage in damages.items():
                d = self.fresh(f"{name}_damaged")

                def prepare(d=d, damage=damage, name=name, argv=argv):
                    self.interrupted(name, argv, d)()
                    damage(d / f"{name}.partial.parquet")

                self.add_resumed(
                    "run directory",
                    f"{name}: a partial file of {what}",
                    argv,
                    d,
                    before=prepare,
                    stderr_has="starting over (it is replaced)",
                )
        d = self.fresh("storm_spelt")
        self.add_resumed(
            "run directory",
            "storm: resume with a defense named twice (the same run)",
            ["storm", *self.STORM, "--defense", "none", "guard", "guard"],
            d,
            before=self.interrupted("storm", ["storm", *self.STORM, "--defense", "none", "guard"], d),
        )
        d = self.fresh("state_swapped")

        def swapped(d=d):
            self.interrupted("storm", ["storm", *self.STORM, "--defense", "none", "guard"], d)()
            (d / "storm.partial.parquet").rename(d / "state.partial.parquet")

        self.add(
            "run directory",
            "state: a storm's partial file as state's",
            ["state", *self.STATE, "--out", d],
            before=swapped,
        )

    @staticmethod
    def file_exists(path):
        def check(_out):
            assert path.is_file(), f"no {path}"

        return check

    def oversize_cases(self):
        self.add(
            "memory",
            "--n 50000000",
            ["render", "--scene", "spheres", "--n", "50000000", "--out", self.fresh("o").with_suffix(".npz")],
        )
        self.add(
            "memory",
            "--n 9000000 (binding limit)",
            [
                "render",
                "--scene",
                "spheres",
                "--n",
                "9000000",
                "--views",
                "1",
                "--size",
                "16x16",
                "--out",
                self.fresh("o").with_suffix(".npz"),
            ],
            env={"SEUWGPU_HOST_MEMORY": str(10**12)},
        )
        storm = ["storm", "--scene", "spheres", "--n", "50", "--size", "16x16", "--out", self.fresh("storm")]
        self.add("memory", "storm --frames 1000000000", [*storm, "--k", "1", "--frames", "1000000000"])
        self.add("memory", "storm --k 1000000000", [*storm, "--k", "1000000000", "--frames", "2"])
        small = {"SEUWGPU_HOST_MEMORY": str(2 * 10**9)}
        for name, extra in {
            "64 views of 2048x2048, 2 GB host": ["--views", "64", "--size", "2048x2048"],
            "one view of 20000x20000, 2 GB host": ["--views", "1", "--size", "20000x20000"],
            "--scale 16, 2 GB host": ["--views", "1", "--size", "2048x2048", "--scale", "16"],
        }.items():
            out = self.fresh("o").with_suffix(".npz")
            self.add("memory", name, ["render", "--n", "50", *extra, "--out", out], env=small)
        out = self.fresh("o").with_suffix(".npz")
        # a frame over one storage binding (lavapipe: 128 MiB, 8.4 Mpx) is rendered in bands
        self.add(
            "memory",
            "one 4096x2112 view: bands of tile rows",
            ["render", "--n", "80", "--views", "1", "--size", "4096x2112", "--out", out],
            "ok",
            self.npz_shape(out, (1, 2112, 4096, 3)),
        )
        self.add(
            "memory",
            "little host memory",
            ["render", "--n", "100000", "--out", self.fresh("o").with_suffix(".npz")],
            env={"SEUWGPU_HOST_MEMORY": "100000000"},
        )
        for name, samples in (("samples = 1000000000000", "1000000000000"), ("samples = 10**15", "1000000000000000")):
            p = self.fresh("spec").with_suffix(".toml")
            p.write_text(spec_text(single=f'[single]\nsamples = {samples}\ndefenses = ["none"]\n'))
            self.add("memory", name, ["campaign", p, "--out", self.fresh("run"), "--quiet"])
        p = self.fresh("spec").with_suffix(".toml")
        p.write_text(spec_text(scene='scene = "spheres"\nn = 50000000\n'))
        self.add("memory", "spec n = 50000000", ["campaign", p, "--out", self.fresh("run"), "--quiet"])
        p = self.fresh("spec").with_suffix(".toml")
        p.write_text(spec_text(single="", extra="[sizes]\nn = [100, 60000000]\nsamples = 1\n"))
        self.add("memory", "sizes.n up to 60000000", ["campaign", p, "--out", self.fresh("run"), "--quiet"])


def run_in_process(case: Case) -> Outcome:
    out, err = io.StringIO(), io.StringIO()
    old_env = {k: os.environ.get(k) for k in case.env}
    os.environ.update(case.env)
    rc, tb = None, False
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("default")
            try:
                rc = main([str(a) for a in case.argv])
            except SystemExit as e:  # argparse
                rc = e.code if isinstance(e.code, int) else 2
            except BaseException:  # noqa: BLE001 - a traceback is what the battery looks for
                tb = True
                err.write(traceback.format_exc())
    finally:
        for k, v in old_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return Outcome(rc, out.getvalue(), err.getvalue(), tb)


def command(argv):
    return [sys.executable, "-m", "seuwgpu", *[str(a) for a in argv]]


GRACEFUL = {signal.SIGINT: (130, b"interrupted"), signal.SIGTERM: (143, b"terminated (SIGTERM)")}


def holds_lock(out_dir: Path, command: str, pid: int) -> bool:
    """Whether process `pid` holds a storm's or state's lock on out_dir (the lock file names the
    process that took it; the file stays when its run ends)."""
    try:
        return (out_dir / f".lock-{command}").read_text().startswith(f"pid {pid} ")
    except OSError:
        return False


def progress_sign(case: Case, out_dir: Path, proc, started: float, parts_before: int) -> bool:
    """Whether the run `proc` shows what the case's kill waits for (Case.kill_after)."""
    command = str(case.argv[0])
    if case.kill_after == "lock":
        return holds_lock(out_dir, command, proc.pid)
    if case.kill_after == "save":
        partial = out_dir / f"{command}.partial.parquet"
        return partial.exists() and partial.stat().st_mtime >= started
    return out_dir.exists() and len(store.part_files(out_dir)) > parts_before


def kept_after(case: Case, out_dir: Path) -> tuple[str, str]:
    """(what an interrupted run left, a fault in it or ""): a campaign's parts must all be
    whole, a storm's or state's partial file readable (pyarrow)."""
    command = str(case.argv[0])
    if command in ("storm", "state"):
        partial = out_dir / f"{command}.partial.parquet"
        if not partial.exists():
            return "no partial records", ""
        import pyarrow.parquet as pq

        try:
            return f"{pq.read_metadata(partial).num_rows} partial records", ""
        except (OSError, ValueError) as e:
            return "", f"{partial.name} unreadable after the interrupt: {e}"
    parts = store.part_files(out_dir) if out_dir.exists() else []
    broken = [p.name for p in parts if not store.part_rows(p)]
    return f"{len(parts)} parts", (f"damaged parts after the interrupt: {broken}" if broken else "")


def interrupt_once(case: Case, env=None) -> tuple[int, bytes, bool]:
    """Run the case's command and send it the case's signal `delay` s after its sign of progress
    (Case.kill_after): (exit status, stderr, whether it had ended before the signal)."""
    sig, delay, _ = case.kill
    out_dir = Path(case.argv[case.argv.index("--out") + 1])
    before = len(store.part_files(out_dir)) if out_dir.exists() else 0
    started = time.time()
    proc = subprocess.Popen(command(case.argv), cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    while proc.poll() is None and time.time() - started < 120:
        if progress_sign(case, out_dir, proc, started, before):
            break
        time.sleep(0.02)
    time.sleep(delay)
    ended = proc.poll() is not None
    if not ended:
        proc.send_signal(sig)
    _, e = proc.communicate(timeout=60)
    return proc.returncode, e, ended


def run_process(case: Case, timeout: float = 300) -> Outcome:
    env = dict(os.environ, **case.env)
    if case.concurrent:  # hold the directory with a first run, start a second one on it
        first = subprocess.Popen(command(case.argv), cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        out_dir = Path(case.argv[case.argv.index("--out") + 1])
        command_name = str(case.argv[0])
        t0 = time.time()
        while time.time() - t0 < 60 and first.poll() is None:
            if command_name in ("storm", "state"):
                if holds_lock(out_dir, command_name, first.pid):
                    break
            elif (out_dir / "manifest.json").exists():
                break
            time.sleep(0.1)
        p = subprocess.run(command(case.argv), cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
        still = first.poll() is None
        first.kill()
        first.wait()
        o = Outcome(p.returncode, p.stdout, p.stderr, "Traceback" in p.stderr)
        if not still:  # the first run had ended: the second one was never refused for it
            o.notes = "the first run had ended before the second one did"
        return o
    notes = []
    if case.kill:  # interrupt `times` runs, each `delay` s after its sign of progress, then finish
        sig, _, times = case.kill
        out_dir = Path(case.argv[case.argv.index("--out") + 1])
        for _ in range(times):
            rc, e, ended = interrupt_once(case, env)
            kept, fault = kept_after(case, out_dir)
            how = " (it had ended)" if ended else " (exit 0: it ended as the signal came)" if rc == 0 else ""
            notes.append(f"{signal.Signals(sig).name} at {kept}{how}")
            if b"Traceback" in e:
                return Outcome(rc, "", e.decode(), True)
            if sig in GRACEFUL:
                code, said = GRACEFUL[sig]
                if rc not in (0, code):
                    return Outcome(rc, "", e.decode())
                if rc == code and said not in e:
                    name = signal.Signals(sig).name
                    return Outcome(1, "", f"{name} without the '{said.decode()}' message: " + e.decode())
                if rc == code and fault:
                    return Outcome(0, "", e.decode(), wrong=fault)
    try:
        p = subprocess.run(command(case.argv), cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return Outcome(None, "", "", timeout=True)
    return Outcome(p.returncode, p.stdout, p.stderr, "Traceback" in p.stderr, notes="; ".join(notes))


def classify(case: Case, o: Outcome) -> tuple[str, str]:
    if o.traceback:
        return "traceback", o.err.strip().splitlines()[-1] if o.err.strip() else ""
    if o.timeout:
        return "crash", "timed out"
    if o.wrong:
        return "silent wrong", o.wrong
    last = o.err.strip().splitlines()[-1] if o.err.strip() else ""
    if o.rc in (2, 3):
        errors = [line for line in o.err.splitlines() if "error:" in line or "seuwgpu view:" in line]
        if len(errors) == 1 or (o.rc == 3 and "view" in case.argv[:1]):
            return ("clear error" if case.expect == "error" else "refused"), last
        return "crash", f"exit {o.rc} without a one-line error: {last}"
    if o.rc == 0:
        if case.expect == "error":
            return "silent wrong", "exit 0 where an error was due"
        if case.check is not None:
            try:
                case.check(o.out)
            except Exception as e:  # noqa: BLE001
                return "silent wrong", f"result check failed: {type(e).__name__}: {e}"[:300]
        if case.stderr_has and case.stderr_has not in o.err:
            return "silent wrong", f"no '{case.stderr_has}' on stderr: {last}"[:300]
        return "correct", o.notes
    return "crash", f"exit status {o.rc}: {last}"


CLASSES = ("clear error", "correct", "refused", "traceback", "crash", "silent wrong")


def select(cases: list, only: str | None) -> list:
    """The cases whose category or name contains `only` (all without it), with the cases they read
    the results of (a resumed storm's uninterrupted reference), in the battery's order. Without
    those, `--only arguments` ran "storm: a partial file of no run arguments" alone and classed it
    silent wrong for want of the reference run's records."""
    chosen = {id(c) for c in cases if not only or only in c.category or only in c.name}
    needed = {c.needs for c in cases if id(c) in chosen and c.needs}
    return [c for c in cases if id(c) in chosen or c.name in needed]


def main_battery(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="JSON file for every case's outcome")
    ap.add_argument("--only", help="run only cases whose category or name contains this")
    ap.add_argument("--work", type=Path, help="scratch folder (default: a temporary one, removed afterwards)")
    args = ap.parse_args(argv)
    # a battery started with & by a shell without job control inherits SIGINT ignored, and so
    # would every command it starts (an ignored signal stays ignored across exec): the SIGINT
    # cases would then test nothing. Caught here, it is the default again in the commands.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    work = args.work or Path(tempfile.mkdtemp(prefix="seuwgpu-battery-"))
    work.mkdir(parents=True, exist_ok=True)
    os.chdir(work)  # relative outputs (e.g. an --out without a folder) land here
    b = Battery(work)
    b.files()
    b.format_files()
    for group in (
        b.spec_cases,
        b.camera_cases,
        b.model_cases,
        b.format_cases,
        b.argument_cases,
        b.run_dir_cases,
        b.interruption_cases,
        b.partial_run_cases,
        b.oversize_cases,
    ):
        group()
    cases = select(b.cases, args.only)
    results, t0 = [], time.time()
    for i, case in enumerate(cases, 1):
        t = time.time()
        try:
            if case.before is not None:
                case.before()
        except Exception as e:  # noqa: BLE001 - the battery's own set-up: said, the other cases run
            cls, detail, o = "crash", f"the case's set-up failed: {type(e).__name__}: {e}"[:300], Outcome(None, "", "")
        else:
            o = run_process(case) if case.process or case.kill or case.concurrent else run_in_process(case)
            cls, detail = classify(case, o)
        results.append(
            {
                "category": case.category,
                "name": case.name,
                "argv": [str(a) for a in case.argv],
                "expect": case.expect,
                "class": cls,
                "exit": o.rc,
                "detail": detail,
                "seconds": round(time.time() - t, 2),
            }
        )
        mark = "" if cls in ("clear error", "correct") else "   <-- " + cls
        print(f"[{i:3d}/{len(cases)}] {case.category:13s} {case.name[:50]:50s} {cls}{mark}", flush=True)
        if mark:
            print(f"        {detail[:200]}", flush=True)
    cats = sorted({r["category"] for r in results})
    print(f"\n{'category':14s}" + "".join(f"{c:>14s}" for c in CLASSES) + f"{'total':>8s}")
    for cat in [*cats, "all"]:
        rows = [r for r in results if cat in ("all", r["category"])]
        print(f"{cat:14s}" + "".join(f"{sum(r['class'] == c for r in rows):14d}" for c in CLASSES) + f"{len(rows):8d}")
    summary = {c: sum(r["class"] == c for r in results) for c in CLASSES}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {"summary": summary, "cases": len(results), "seconds": round(time.time() - t0, 1), "results": results},
            indent=1,
        )
    )
    print(f"\n{len(results)} cases in {time.time() - t0:.0f} s; wrote {args.out}")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if summary["traceback"] == summary["crash"] == summary["silent wrong"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main_battery())
