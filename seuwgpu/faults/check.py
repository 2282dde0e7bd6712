"""Check stage: shaders/check.wgsl, the per-primitive checks of the parity, checksum and
scale-class defenses over a renderer's stored chunks; twin: faults/defenses.py `detect`.

The side data is computed from the clean model once, like the guard's box, and uploaded packed
(`side_bits` per primitive, side.pack_side), so the device holds what the memory column
charges (side.device_bytes). A check is one dispatch per chunk and one 4-byte read of the
detection count; only when it is non-zero does the host read the flag bits and repair (cull,
reload or clamp: defenses.repair), and clear them for the next check.

The checker's own state (issue 47): its parameters carry a seal (`seal_words`, a hash of every
parameter and of the table) that the shader verifies; a mismatch (an upset in the uniform
buffer) makes `run` rewrite the parameters from the host's copy and check again
(`param_faults` counts them). The detection count is kept twice, so one upset in it cannot hide
a detection. What one upset in the side data or the flag bits does is stated in
docs/defenses.md and measured by tools/checker_state.py.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults import side as sd
from seuwgpu.faults.codes import CHECKSUM_SEED, fmix32
from seuwgpu.faults.codes import checksum as codes_checksum
from seuwgpu.faults.guard import fill_chunk_params
from seuwgpu.gpu.device import STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms


class Checker:
    """One defense's check over a renderer's stored chunks (`run` -> flagged count, `flags`)."""

    def __init__(self, renderer, defense: str, clean_rows: np.ndarray, box=None):
        d = dfn.checked(defense)
        r, L = renderer, renderer.layout
        g = self.gpu = r.gpu
        self.layout, self.chunks, self.defense = L, r.chunks, defense
        self.kernel = Kernel(g, "check")
        side = d.side_data(np.asarray(clean_rows), L.precision, L.degree, box)
        self.side = g.upload(sd.pack_side(side, d.side_bits))
        table = np.asarray(d.check_table(box, L.precision), np.float32)
        self.table = g.upload(table)
        self.out = CheckOutput(g, L.n, "check.out")
        self._flagged = False  # flag bits set by the last run (cleared before the next)
        self.params = Uniforms(g, self.kernel.struct("CheckParams"), L.n_chunks, "check.params")
        fill_chunk_params(
            self.params,
            L,
            mode=self.kernel.const(d.check_mode),
            side_bits=d.side_bits,
            table_len=table.size,
            **d.check_parameters(L.precision, L.degree),
        )
        self.params.rows["seal"] = seal_words(self.params.rows, table)
        self.params.write()
        self.param_faults = 0  # runs that found their parameters upset (and were rerun)

    def encode(self, enc):
        for k in range(self.layout.n_chunks):
            self.kernel.dispatch(
                enc,
                params=self.params.binding(k),
                side=self.side,
                words=self.chunks[k],
                table=self.table,
                out=self.out.buffer,
                threads=self.layout.chunk_range(k)[1] - self.layout.chunk_range(k)[0],
            )

    def run(self) -> int:
        """Check every primitive; returns how many are flagged (one small read). Parameters found
        upset are rewritten from the host's copy and the check run again."""
        for _ in range(2):
            if self._flagged:
                self.out.clear()
            else:
                self.out.clear_header()
            enc = self.gpu.device.create_command_encoder()
            self.encode(enc)
            self.gpu.submit(enc)
            head = self.out.header(CheckOutput.FAULTS + 1)
            count = CheckOutput.count(head)
            self._flagged = True  # flags may be set: cleared before the next run
            if not head[CheckOutput.FAULTS]:
                break
            self.param_faults += 1
            self.params.write()
        self._flagged = count > 0 or bool(head[CheckOutput.FAULTS])
        return count

    def flags(self) -> np.ndarray:
        """[n] bool: the primitives the last run flagged."""
        return self.out.flags()

    def device_bytes(self) -> int:
        """Bytes of this check's buffers on the device (side.device_bytes counts the same)."""
        return int(self.side.size + self.table.size + self.out.buffer.size + self.params.buffer.size)


class CheckOutput:
    """The output buffer of both checks, as shaders/codes.wgsl's OUT_* words lay it out (read
    from there): the detection count twice (an upset in one copy hides nothing), then each
    check's own two words (the check's parameter faults; the device repair's failed golden rows
    and repaired primitives), then one flag bit per primitive (bit g % 32 of word g / 32)."""

    DETECTED, DETECTED_COPY, FAULTS, REPAIRED, FLAGS = (
        sd.OUT_WORDS[f"OUT_{w}"] for w in ("DETECTED", "DETECTED_COPY", "FAULTS", "REPAIRED", "FLAGS")
    )
    HEADER_WORDS = FLAGS

    def __init__(self, gpu, n: int, label: str):
        self.gpu, self.n = gpu, n
        self.flag_words = -(-n // 32)
        self.buffer = gpu.buffer(4 * (self.HEADER_WORDS + self.flag_words), STORAGE, label)
        self._zeros = np.zeros(self.HEADER_WORDS + self.flag_words, np.uint32)

    def clear(self):
        """Header and flags zeroed."""
        self.gpu.write(self.buffer, self._zeros)

    def clear_header(self, first: int = 0, count: int = HEADER_WORDS):
        """Header words first .. first + count - 1 zeroed; the flags kept."""
        self.gpu.write(self.buffer, self._zeros[:count], 4 * first)

    def header(self, words: int = HEADER_WORDS) -> np.ndarray:
        """The first `words` header words (one small read)."""
        return self.gpu.read(self.buffer, np.uint32, 0, 4 * words)

    @classmethod
    def count(cls, head: np.ndarray) -> int:
        """The detections a header holds: the larger copy."""
        return int(max(head[cls.DETECTED], head[cls.DETECTED_COPY]))

    def flags(self) -> np.ndarray:
        """[n] bool: the flag bits."""
        words = self.gpu.read(self.buffer, np.uint32, 4 * self.FLAGS, 4 * self.flag_words)
        return np.unpackbits(words.view(np.uint8), bitorder="little")[: self.n].astype(bool)


def seal_words(rows: np.ndarray, table: np.ndarray) -> np.ndarray:
    """[slots] u32: each CheckParams slot's seal, h = fmix32(h ^ word) over its words before the
    seal, then over the table's words (twin of shaders/check.wgsl params_seal)."""
    fields = [f for f in rows.dtype.names if f != "seal"]
    h = np.full(rows.shape[0], CHECKSUM_SEED, np.uint64)
    for f in fields[: fields.index("table_len") + 1]:
        h = fmix32(h ^ rows[f].astype(np.uint64))
    for w in np.asarray(table, np.float32).view(np.uint32):
        h = fmix32(h ^ np.uint64(w))
    return h.astype(np.uint32)


class FrameCheck:
    """The check inside the frame (issue 47): a frame-check defense's parity code (defenses.
    FrameParity: parity4f, parity2f) of every primitive verified where the projection reads it
    (shaders/project.wgsl FRAME_CHECK); a primitive that fails is dropped from that frame (culled,
    as a non-finite mean is), counted and, for a defense that keeps flags, flagged for repair, so
    a detected upset is never drawn. Twin: the frame of the model with the failing primitives'
    means set to NaN (codes.cull), the failing ones those of FrameParity.hit.

    Side data: the codes, packed (side.pack_side), and the output as Checker's (a count kept twice,
    then, with flags, a flag bit per primitive). `frame_count()` is the count as the last frame
    left it, read back with that frame's own stats (Renderer.carry_back: no read of its own, what
    decides a repair every frame); `count()` reads it now, `flags()` the flag bits, `clear()`
    zeroes them after a repair."""

    def __init__(self, renderer, clean_rows: np.ndarray, defense: str = "parity4f"):
        d = dfn.get(defense)
        if not d.frame_check:
            ok = ", ".join(x.name for x in dfn.REGISTRY.values() if x.frame_check)
            raise ValueError(f"defense {defense!r} is not checked inside the frame; those that are: {ok}")
        r, L = renderer, renderer.layout
        self.renderer, self.gpu, self.layout, self.defense = r, r.gpu, L, d
        # a per-word code's pair of primitive p is p >> 1, the word j >> 1 of its chunk: chunks start
        # at even primitives (fields.StoredLayout), so a pair never splits
        assert L.chunk_prims % 2 == 0, "a stored word pair split between chunks"
        side = d.side_data(np.asarray(clean_rows), L.precision, L.degree)
        self.side = r.gpu.upload(sd.pack_side(side, d.side_bits))
        self.out = CheckOutput(r.gpu, L.n if d.flags else 0, "frame_check.out")
        self.clear()
        self.cover = d.code.cover(L.precision)  # both halves of a word for a per-word code
        self.per_word = d.code.pairs(L.precision)
        self.on()

    def on(self):
        """Check in every frame from now on (the projection's FRAME_CHECK pipelines)."""
        code = self.defense.code
        self.renderer.projection.set_frame_check(
            self.side, self.out.buffer, self.cover, code.ways, code.diagonal, self.defense.flags, self.per_word
        )
        assert CheckOutput.DETECTED_COPY == CheckOutput.DETECTED + 1  # the two words of the count, carried
        self.renderer.carry_back((self.out.buffer, 4 * CheckOutput.DETECTED, 2))

    def off(self):
        """Back to today's projection pipeline."""
        self.renderer.projection.set_frame_check(None)
        self.renderer.carry_back(None)

    def clear(self):
        self.out.clear()

    def count(self) -> int:
        return CheckOutput.count(self.out.header(CheckOutput.DETECTED_COPY + 1))

    def frame_count(self) -> int:
        """The detections as the last frame rendered with this check left them (no read)."""
        carried = self.renderer.carried
        if carried.size != 2:
            raise RuntimeError("no frame was rendered with this check on since it was turned on")
        head = np.zeros(CheckOutput.DETECTED_COPY + 1, np.uint32)
        head[[CheckOutput.DETECTED, CheckOutput.DETECTED_COPY]] = carried
        return CheckOutput.count(head)

    def flags(self) -> np.ndarray:
        """[n] bool: the primitives the frames since the last clear() flagged."""
        if not self.defense.flags:
            raise ValueError(f"{self.defense.name} keeps no flags: its repair re-verifies every primitive")
        return self.out.flags()

    def device_bytes(self) -> int:
        return int(self.side.size + self.out.buffer.size)


class DeviceRepair:
    """Repair on the device (shaders/repair.wgsl): the primitives a FrameCheck flagged (for a code
    without flags: every primitive whose code fails, recomputed in this pass) are rewritten from a
    golden copy of the model held on the device, each golden row's checksum (codes.checksum of
    the clean row, 32 bits a primitive) verified when it is read; a golden row that fails is left
    alone and counted (the primitive stays flagged, dropped every frame). A repaired primitive's
    code is rewritten from the golden row too, so an upset in the code bits (a clean primitive
    failing every frame) is repaired by the same pass. A per-word code (parity2f at fp16/bf16)
    is verified once a stored word, and a word that fails is rewritten whole (both primitives,
    counted as two repaired) once both golden rows pass their checksums, its code from the golden
    words. No host copy of the model is read: the host reads two counts.

    Device memory: the golden copy (the model's size again) and its checksums; `device_bytes`."""

    def __init__(self, renderer, clean_rows: np.ndarray, frame_check: FrameCheck):
        r, L = renderer, renderer.layout
        self.renderer, self.gpu, self.layout, self.check = r, r.gpu, L, frame_check
        code = frame_check.defense.code
        self.kernel = Kernel(
            r.gpu,
            "repair",
            constants={
                "REPAIR_FLAGS": int(frame_check.defense.flags),
                "CODE_COVER": frame_check.cover,
                "CODE_WAYS": code.ways,
                "CODE_DIAGONAL": code.diagonal,
                "CODE_PER_WORD": int(frame_check.per_word),
            },
        )
        self.golden = [r.gpu.upload(w, STORAGE, f"golden-chunk-{k}") for k, w in enumerate(r.clean_words)]
        self.golden_sum = r.gpu.upload(codes_checksum(np.asarray(clean_rows)))
        self.params = Uniforms(r.gpu, self.kernel.struct("RepairParams"), L.n_chunks, "repair.params")
        fill_chunk_params(self.params, L)
        self.params.write()

    def run(self) -> tuple[int, int]:
        """Repair every flagged (or failing) primitive; returns (repaired, golden rows that failed
        their checksum)."""
        g, L = self.gpu, self.layout
        out = self.check.out
        out.clear_header(CheckOutput.FAULTS, 2)  # this run's counts
        enc = g.device.create_command_encoder()
        per = 1 if L.precision == "fp32" else 2
        for k in range(L.n_chunks):
            lo, hi = L.chunk_range(k)
            self.kernel.dispatch(
                enc,
                params=self.params.binding(k),
                words=self.renderer.chunks[k],
                golden=self.golden[k],
                golden_sum=self.golden_sum,
                out=out.buffer,
                side=self.check.side,
                threads=-(-(hi - lo) // per),
            )
        g.submit(enc)
        head = out.header()
        if not head[CheckOutput.FAULTS]:  # every flag cleared: the next frame's detections start from zero
            out.clear_header(CheckOutput.DETECTED, 2)
        return int(head[CheckOutput.REPAIRED]), int(head[CheckOutput.FAULTS])

    def device_bytes(self) -> int:
        return int(sum(b.size for b in self.golden) + self.golden_sum.size + self.params.buffer.size)
