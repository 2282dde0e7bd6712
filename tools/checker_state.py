"""What one upset in the checker's own state does (issue 47 point 5), measured on the GPU check.

    python tools/checker_state.py [--scene leica-sofort] [--defense parity4r] [--corrupt 300]

`--corrupt` primitives get a log-scale bit-30 flip; then every bit of every CheckParams word of
chunk 0 is flipped in the uniform buffer the shader reads, once as it is (the seal catches it:
the host rewrites the parameters and checks again) and once re-sealed (what a checker without
the seal saw), and every bit of the first side-data word. Per target: flips, flips the seal
caught, flips after which some corrupted primitive went unflagged, flips that flagged clean ones.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.faults.check import Checker, seal_words  # noqa: E402
from seuwgpu.faults.guard import stored_box  # noqa: E402
from seuwgpu.gpu.kernel import as_bytes  # noqa: E402
from seuwgpu.model import encoding  # noqa: E402
from seuwgpu.model.scenes import make_scene, scene_cameras  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="leica-sofort")
    ap.add_argument("--defense", default="parity4r")
    ap.add_argument("--corrupt", type=int, default=300)
    a = ap.parse_args(argv)
    model = make_scene(a.scene)
    r = Renderer(model, scene_cameras(a.scene, 1, 32, 32), "fp32")
    clean = encoding.to_bits(model.flat(), "fp32")
    box = stored_box(r.layout, r.clean_words, "fp32")
    bad = clean.copy()
    hit = np.random.default_rng(0).choice(model.n, a.corrupt, replace=False)
    bad[hit, 3] ^= np.uint32(1 << 30)
    for c, words in enumerate(r.layout.encode_bits(bad)):
        r.gpu.write(r.chunks[c], words)
    chk = Checker(r, a.defense, clean, box)
    assert chk.run() == a.corrupt
    table = chk.gpu.read(chk.table, np.float32, 0, chk.table.size)[: int(chk.params.rows["table_len"][0])]
    print(f"{a.scene} ({model.n:,} primitives, {r.layout.n_chunks} chunk(s)), {a.defense}, {a.corrupt} corrupted")
    print("| target | flips | caught by the seal | some corrupted primitive unflagged | clean ones flagged |")
    print("|---|---:|---:|---:|---:|")

    def outcome():
        chk.run()
        f = chk.flags()
        return (not f[hit].all()), int(f.sum() - f[hit].sum()) > 0

    for field in [n for n in chk.params.rows.dtype.names]:
        for sealed in (True, False):
            caught = missed = false = 0
            for b in range(32):
                upset = chk.params.rows.copy()
                upset[field][0] ^= np.uint32(1 << b)
                if not sealed:
                    upset["seal"] = seal_words(upset, table)
                r.gpu.write(chk.params.buffer, as_bytes(upset))
                before = chk.param_faults
                m, f = outcome()
                caught += chk.param_faults > before
                missed += m
                false += f
                chk.params.write()
            label = field if sealed else f"{field} (re-sealed: no seal)"
            if field != "seal" or sealed:
                print(f"| {label} | 32 | {caught} | {missed} | {false} |")
    side = chk.gpu.read(chk.side, np.uint32, 0, 4)
    caught = missed = false = 0
    for b in range(32):
        chk.gpu.write(chk.side, side ^ np.array([1 << b, 0, 0, 0], np.uint32))
        m, f = outcome()
        missed += m
        false += f
    chk.gpu.write(chk.side, side)
    print(f"| side data, word 0 | 32 | 0 | {missed} | {false} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
