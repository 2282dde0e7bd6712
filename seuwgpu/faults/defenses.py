"""Every defense in one place: one object per defense, registered once here (`register`), that
says what it is (name, label, info), what it stores beside the model, what the renderer reads
through it from a corrupted primitive (the numpy twin every evaluation uses), and, for the
defenses with a GPU check, the check's side data, detection and repair.

The CLI, the spec, the engine, the GPU check, the cost report, the storm, the viewer and the
analyses ask these objects (`get(name)`, `DEFENSES`); none of them lists defense names.

A defense reads the stored primitive as it is now (`corrupt`, stored bit patterns [M, ncomp]) and
knows what it stored alongside the clean model (parity bits, checksums, scale classes, boxes: all
functions of the clean primitive, so the twins take the clean rows and recompute them). Every
defense is the identity on the clean model (tests/test_defenses.py).

The kinds (classes below): `Defense` (none: reads the corrupted bits), `SupportGuard` (the
guard's box clamp, applied in the pipeline: faults/guard.py; its `read` returns the corrupted
bits and `guard_fields` names what the pipeline clamps), `FrameParity` (a parity code checked
inside every frame, in the projection: parity4f, parity2f), `Ecc`, `EccCritical` and
`Duplication` (read-time codes, modelled by what they read), `CellBox` (per-cell boxes), and
`CheckedDefense` (a per-primitive check on the GPU, shaders/check.wgsl: `Parity`, `Checksum`,
`ScaleBound`), which flags a primitive and then culls it (its mean set to NaN: the one corrupted
primitive the renderer draws nothing for), reloads it from the golden copy (host memory or the
model file, not charged to device memory) or clamps it. The checksum's step, h = fmix32(h ^
value) (MurmurHash3's finaliser), is a bijection of the running hash, so any change confined to
one stored value is detected with certainty; four interleaved parities (bit position mod 4)
catch every burst of up to 4 adjacent bits.

The code mathematics lives in faults/codes.py, the side data's device bytes and the memory
columns in faults/side.py, a check's schedule (exposure, time as a schedule) in
faults/schedule.py; this module holds the defense objects and the one registry.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.faults.codes import (
    CELL_GRID,
    CRITICAL_FIELDS,
    GUARD_FIELDS,
    SCALE_CLASS_BITS,
    SCALE_CLASSES,
    CellBoxes,
    ParityCode,
    cellbox_read,
    checksum,
    covered_components,
    cull,
    dup_read,
    ecc_check_bits,
    ecc_crit_read,
    ecc_read,
    parity_cover_mask,
    scale_classes,
    scale_table,
)
from seuwgpu.faults.schedule import Exposure, exposure
from seuwgpu.model import checks, encoding
from seuwgpu.model.fields import FIELDS, n_components


# ---- the defenses ------------------------------------------------------------------------------
class Defense:
    """One defense. This base is "none": it stores nothing and reads the corrupted bits.

    A subclass overrides what differs: `read` (the twin of what the renderer reads), the bits it
    stores (`bits_per_primitive`, `bits_per_model`), `guard_fields` (the fields the in-pipeline
    support guard clamps for it), `model_state` (state built once from the clean model, such as
    cellbox's boxes), and for a GPU check the members of `CheckedDefense`."""

    guard_fields: tuple[str, ...] = ()  # fields the pipeline's support guard clamps (faults/guard.py)
    reads_stored_bits = True  # `read` returns the stored bits as they are (none, the guards)
    has_model_state = False  # `model_state` builds something from the clean model
    check_mode: str | None = None  # its check's MODE_* const in shaders/check.wgsl, by name; None: no check
    writes_back = False  # its repair rewrites the stored model (a storm keeps the repair)
    frame_check = False  # checked inside every frame (FrameParity); `after_frame` is its repair

    def __init__(self, name: str, info: str, label: str = "", first_study: bool = False):
        self.name, self.info, self.label = name, info, label or name
        self.first_study = first_study  # one of the first study's defenses (guard variants, ECC, TMR)

    def __repr__(self) -> str:
        return f"<defense {self.name}>"

    @property
    def checked(self) -> bool:
        return self.check_mode is not None

    def upset_exposure(self, check_every: int) -> Exposure:
        """Frames drawn from a corrupted model before it acts: a check's schedule (`exposure`);
        none for one that changes what every read returns (a guard, a correction, a vote); for
        one that reads the stored bits as they are and guards nothing, until a reload."""
        if self.checked:
            return exposure(check_every)
        return exposure(0 if self.reads_stored_bits and not self.guard_fields else 1)

    def bits_per_primitive(self, precision: str, degree: int) -> int:
        """Stored bits it adds per primitive."""
        return 0

    def bits_per_model(self, precision: str, degree: int) -> int:
        """Stored bits it adds once per model (boxes, tables): a support guard's box, 2 fp32 bounds
        per guarded component."""
        return 2 * 32 * covered_components(self.guard_fields, degree).size

    def model_state(self, clean_rows: np.ndarray, precision: str, degree: int):
        """What it builds once from the clean model beyond the box (None: nothing)."""
        return None

    def read(self, clean, corrupt, precision: str, degree: int, box=None, prims=None, state=None) -> np.ndarray:
        """What the renderer reads from primitives whose stored bits went from `clean` to
        `corrupt` ([M, ncomp] each); the in-pipeline guard clamp is applied later."""
        return corrupt

    def read_variants(self, clean, corrupt, precision: str, degree: int, box=None, prims=None, state=None):
        """`read` of independent variants: row i is a model where primitive `prims[i]` alone went
        from `clean[i]` to `corrupt[i]` (the batched evaluator's rows; a primitive may repeat)."""
        return self.read(clean, corrupt, precision, degree, box, prims, state)

    def drops_partners(self, precision: str) -> bool:
        """A detected upset's frame also drops a clean primitive beside the hit one (a per-word
        frame code's pair partner at this precision: FrameParity), which one-primitive variants
        (the incremental evaluator, worstcase, sort-first regions) do not draw."""
        return False

    def drops_partner(self, clean, corrupt, precision: str, degree: int) -> np.ndarray:
        """[M] bool: of such variants, those whose frame also drops their partner (drops_partners)."""
        return np.zeros(np.asarray(corrupt).shape[0], bool)

    def after_frame(self, clean, corrupt, precision: str, degree: int, prims=None):
        """The stored rows after a frame when a repair lands between frames (FrameParity); None:
        the frame changes nothing stored. `prims`: the rows' primitives (None: the whole model)."""
        return None

    def partners(self, prims, n: int, precision: str) -> np.ndarray:
        """`prims` and the primitives its twins need beside them (the pair partners of a per-word
        frame code, FrameParity): what a caller evaluating a subset of the model includes."""
        return np.asarray(prims, np.int64)

    def frame(self, clean, corrupt, precision: str, degree: int, box=None, prims=None, state=None):
        """(read, after_frame) of one frame, together: a frame check computes its check once."""
        return self.read(clean, corrupt, precision, degree, box, prims, state), self.after_frame(
            clean, corrupt, precision, degree, prims
        )


class SupportGuard(Defense):
    """The support guard: `fields` clamped into the clean model's box while projecting (the
    pipeline does it; memory is untouched). Stores the box: 2 fp32 bounds per guarded component."""

    def __init__(self, name, info, fields, label="", first_study=False):
        super().__init__(name, info, label, first_study)
        self.guard_fields = tuple(fields)


class Ecc(Defense):
    reads_stored_bits = False

    def bits_per_primitive(self, precision, degree):
        return ecc_check_bits(precision) * n_components(degree)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return ecc_read(clean, corrupt, precision)


class Duplication(Defense):
    reads_stored_bits = False

    def bits_per_primitive(self, precision, degree):
        return 2 * n_components(degree) * encoding.bits_per_value(precision)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return dup_read(clean, corrupt)


class EccCritical(Defense):
    reads_stored_bits = False

    def bits_per_primitive(self, precision, degree):
        return ecc_check_bits(precision) * covered_components(CRITICAL_FIELDS, degree).size

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return ecc_crit_read(clean, corrupt, precision, degree)


class CellBox(Defense):
    reads_stored_bits = False
    has_model_state = True

    def bits_per_primitive(self, precision, degree):
        return 9

    def bits_per_model(self, precision, degree):
        return 2 * 32 * covered_components(GUARD_FIELDS, degree).size * CELL_GRID**3

    def model_state(self, clean_rows, precision, degree):
        return CellBoxes(clean_rows, precision, degree)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        if state is None or prims is None:
            raise ValueError("cellbox needs the primitives' indices and the model's cell boxes")
        return cellbox_read(clean, corrupt, prims, state)


class CheckedDefense(Defense):
    """A per-primitive check that runs on the GPU (shaders/check.wgsl, faults/check.py): side
    data computed from the clean model once, a check that flags primitives, and a repair."""

    reads_stored_bits = False

    side_bits = 32  # bits of side data per primitive
    table_words = 1  # f32 words of its check's table (`check_table`)
    reloads = False  # a flagged primitive is reloaded from the golden copy (off the device)
    writes_back = True

    def bits_per_primitive(self, precision, degree):
        return self.side_bits

    def check_parameters(self, precision: str, degree: int) -> dict:
        """The CheckParams fields of its check besides the chunk's (parity ways and cover)."""
        return {"ways": 4, "cover": 0, "comp_count": 0}

    def check_table(self, box, precision: str) -> np.ndarray:
        """The f32 table its check reads (scalebound's class bounds; one placeholder word otherwise)."""
        return np.zeros(self.table_words, np.float32)

    def side_data(self, clean, precision: str, degree: int, box=None) -> np.ndarray:
        """[M] u32: what it stores with each clean primitive."""
        raise NotImplementedError

    def detect(self, side, rows, precision: str, degree: int, box=None) -> np.ndarray:
        """[M] bool: the check flags the primitive (stored `rows` against `side`). Twin of
        shaders/check.wgsl."""
        return self.side_data(rows, precision, degree, box) != np.asarray(side, dtype=np.uint32)

    def repair(self, clean, corrupt, hit, precision: str, box=None, side=None) -> np.ndarray:
        """What a flagged primitive becomes; unflagged rows are returned as they are."""
        if self.reloads:
            return np.where(hit[:, None], clean, corrupt)
        return cull(corrupt, hit, precision)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        side = self.side_data(clean, precision, degree, box)
        hit = self.detect(side, corrupt, precision, degree, box)
        return self.repair(clean, corrupt, hit, precision, box, side)


class Parity(CheckedDefense):
    """`code` (codes.ParityCode: interleaved parity bits over the sign, exponent and top
    PARITY_MANTISSA mantissa bits of the values of its fields) checked on the GPU every S frames;
    a mismatch culls or reloads."""

    check_mode = "MODE_PARITY"

    def __init__(self, name, info, code: ParityCode, reloads: bool, label="", first_study=False):
        super().__init__(name, info, label, first_study)
        if code.diagonal or code.per_word:  # check.wgsl's MODE_PARITY folds neither: its side data would disagree
            raise ValueError("a periodic parity check (check.wgsl) has no diagonal ways nor per-word codes")
        self.code, self.reloads = code, reloads
        self.ways, self.fields = code.ways, code.fields
        self.side_bits = code.ways

    def components(self, degree: int) -> int:
        return self.code.components(degree)

    def check_parameters(self, precision, degree):
        return {"ways": self.ways, "cover": parity_cover_mask(precision), "comp_count": self.components(degree)}

    def side_data(self, clean, precision, degree, box=None):
        return self.code.side_data(clean, precision, degree)

    def detect(self, side, rows, precision, degree, box=None):
        """As shaders/check.wgsl computes it (codes.ParityCode.code)."""
        return self.code.detect(side, rows, precision, degree)


class Checksum(CheckedDefense):
    check_mode = "MODE_CHECKSUM"
    reloads = True

    def side_data(self, clean, precision, degree, box=None):
        return checksum(np.asarray(clean))


class ScaleBound(CheckedDefense):
    """The support guard plus a SCALE_CLASS_BITS-bit class per primitive bounding its log-scales
    from above; a flagged primitive's log-scales are clamped to the class bound."""

    check_mode = "MODE_SCALE"
    side_bits = SCALE_CLASS_BITS
    guard_fields = GUARD_FIELDS
    table_words = SCALE_CLASSES

    def check_table(self, box, precision):
        return scale_table(box, precision)

    def side_data(self, clean, precision, degree, box=None):
        if box is None:
            raise ValueError("scalebound needs the clean model's box")
        return scale_classes(np.asarray(clean), scale_table(box, precision), precision).astype(np.uint32)

    def detect(self, side, rows, precision, degree, box=None):
        bound = scale_table(box, precision)[np.asarray(side, dtype=np.int64)]
        vals = encoding.from_bits(np.asarray(rows)[:, 3:6], precision)
        with np.errstate(invalid="ignore"):
            return (vals > bound[:, None]).any(axis=1)

    def repair(self, clean, corrupt, hit, precision, box=None, side=None):
        side = self.side_data(clean, precision, 0, box) if side is None else side
        bound = scale_table(box, precision)[np.asarray(side, dtype=np.int64)]
        vals = encoding.from_bits(corrupt[:, 3:6], precision)
        with np.errstate(invalid="ignore"):
            over = (vals > bound[:, None]) & hit[:, None]
        out = corrupt.copy()
        ls = out[:, 3:6]
        ls[over] = np.broadcast_to(encoding.to_bits(bound, precision)[:, None], ls.shape)[over]
        out[:, 3:6] = ls
        return out


class FrameParity(Defense):
    """A parity code (codes.ParityCode over every stored value) checked inside every frame, where
    the projection reads the primitive (shaders/project.wgsl FRAME_CHECK, faults/check.py
    FrameCheck): a primitive that fails is dropped from that frame (culled); the repair (a reload
    from the golden copy, on the device: DeviceRepair) lands before the next frame. Exposure 0
    frames: a detected upset is never drawn, only missed for one frame. `read` is that frame;
    `after_frame` the repair.

    `flags`: a flag bit per primitive marks what the frame dropped and the repair rewrites only
    those (parity4f); without (parity2f) the frame only counts its detections and the repair
    re-verifies every primitive's code, rewriting those that fail (a full pass, run only after a
    detection), so the device holds the code bits alone.

    `after_frame` repairs every failing primitive. The device's parity4f repairs those a view drew
    (flagged); one no view drew stays corrupt and is dropped from the first frame that would draw
    it, then repaired: frames from fixed views are the same, a moving view can see that primitive
    missing for one more frame than the twin shows.

    A per-word code (`code.per_word`, parity2f) at fp16/bf16 codes each stored word pair of
    primitives (2i, 2i + 1) together: a failing pair is dropped from the frame together (its clean
    partner missing for that frame) and repaired together. The twins given a subset of the
    primitives (`prims`: their indices) group them by pair, every primitive not given being clean
    (`partners` names what a caller must include for the clean partner's drop to be drawn)."""

    reads_stored_bits = False
    frame_check = True

    def __init__(self, name, info, code: ParityCode, flags: bool, label=""):
        super().__init__(name, info, label)
        if code.fields != FIELDS:
            raise ValueError("a check inside the frame covers every stored value (the projection reads them all)")
        if code.per_word and flags:  # the frame flags a primitive, the repair would need its pair's
            raise ValueError("a per-word frame code keeps no flags (its repair re-verifies every word)")
        self.code, self.flags = code, bool(flags)
        self.side_bits = code.ways  # bits of one packed code (a primitive's, or a word pair's)

    def bits_per_primitive(self, precision, degree):
        return self.code.bits_per_primitive(precision)

    def n_codes(self, n: int, precision: str) -> int:
        """Packed codes of n primitives (one a word pair with a per-word code at 16 bits)."""
        return self.code.n_codes(n, precision)

    def partners(self, prims, n: int, precision: str) -> np.ndarray:
        return self.code.partners(prims, n, precision)

    def side_data(self, clean, precision: str, degree: int) -> np.ndarray:
        """[n_codes] u32: the code of each clean primitive, or word pair (what FrameCheck uploads, packed)."""
        return self.code.side_data(clean, precision, degree)

    def hit(self, side, corrupt, precision, degree) -> np.ndarray:
        """[M] bool: the frame's check fails (the code's detect against its side data; `corrupt` the
        whole model, in order)."""
        return self.code.detect(side, corrupt, precision, degree)

    def _hit(self, clean, corrupt, precision, degree, prims=None):
        if prims is None:  # the whole model, in order
            return self.hit(self.side_data(clean, precision, degree), corrupt, precision, degree)
        return self.code.detect_changed(clean, corrupt, prims, precision, degree)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return cull(corrupt, self._hit(clean, corrupt, precision, degree, prims), precision)

    def read_variants(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        """Each variant checked alone (grouping repeated primitives by pair would XOR independent
        variants' code changes together)."""
        return cull(corrupt, self._variant_hit(clean, corrupt, precision, degree), precision)

    def drops_partners(self, precision: str) -> bool:
        return self.code.pairs(precision)

    def drops_partner(self, clean, corrupt, precision: str, degree: int) -> np.ndarray:
        if not self.drops_partners(precision):
            return np.zeros(np.asarray(corrupt).shape[0], bool)
        return self._variant_hit(clean, corrupt, precision, degree)

    def _variant_hit(self, clean, corrupt, precision, degree) -> np.ndarray:
        code = self.code.primitive_code
        return code(clean, precision, degree) != code(corrupt, precision, degree)

    def after_frame(self, clean, corrupt, precision: str, degree: int, prims=None) -> np.ndarray:
        """The stored rows once the frame's detections are repaired: those that fail reloaded."""
        return np.where(self._hit(clean, corrupt, precision, degree, prims)[:, None], clean, corrupt)

    def frame(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        hit = self._hit(clean, corrupt, precision, degree, prims)  # once for the frame and its repair
        return cull(corrupt, hit, precision), np.where(hit[:, None], clean, corrupt)


# ---- the registry ------------------------------------------------------------------------------
PARITY4R = ParityCode(4, FIELDS)  # parity4r's code, which parity4f checks inside the frame
REGISTRY: dict[str, Defense] = {}


def register(defense: Defense) -> Defense:
    """Add a defense to the one list every part of the package reads (in this order)."""
    if defense.name in REGISTRY:
        raise ValueError(f"defense {defense.name!r} is registered twice")
    REGISTRY[defense.name] = defense
    return defense


register(Defense("none", "no protection", first_study=True))
register(
    SupportGuard(
        "guard",
        "support guard: clamp every value except sh_rest into the clean model's box",
        GUARD_FIELDS,
        label="support guard",
        first_study=True,
    )
)
register(
    SupportGuard(
        "selective",
        "support guard on log-scales and opacity only",
        CRITICAL_FIELDS,
        label="selective guard (log-scale + opacity)",
        first_study=True,
    )
)
register(
    Ecc(
        "ecc",
        "SEC-DED Hamming code over every value's sign+exponent bits (corrects single errors)",
        label="ECC sign+exp (SEC-DED)",
        first_study=True,
    )
)
register(
    Duplication(
        "dup",
        "triple modular redundancy with bitwise majority voting",
        label="full duplication (TMR vote)",
        first_study=True,
    )
)
register(
    Parity(
        "parity",
        "1 parity bit per primitive over sign, exponent and top mantissa bits; mismatch culls",
        ParityCode(1, GUARD_FIELDS),  # a cull for an inert sh_rest hit would only harm
        reloads=False,
    )
)
register(
    Parity(
        "parity4",
        "4 interleaved parity bits per primitive (bit mod 4): catch bursts of <= 4 bits; cull",
        ParityCode(4, GUARD_FIELDS),
        reloads=False,
    )
)
register(EccCritical("ecc_crit", "SEC-DED over sign+exponent of log-scales and opacity only; uncorrectable culls"))
register(ScaleBound("scalebound", "support guard plus a 4-bit scale class per primitive bounding its log-scales"))
register(Checksum("checksum", "32-bit checksum per primitive; a mismatch reloads it from the golden copy"))
register(
    Parity(
        "parity4r",
        "parity4's check over every value; a mismatch reloads the primitive from the golden copy",
        PARITY4R,  # a reload is harmless, so it covers every value
        reloads=True,
    )
)
register(
    FrameParity(
        "parity4f",
        "parity4r's check inside every frame (in the projection): a mismatch drops the primitive from that "
        "frame and reloads it before the next",
        PARITY4R,
        flags=True,
        label="parity4r in the frame",
    )
)
register(
    FrameParity(
        "parity2f",
        "2 parity bits per primitive (at fp16/bf16 per stored word pair: 1 bit a primitive) over every value, "
        "bit b of value c in way (b + c) mod 2, checked inside every frame: a mismatch drops the primitive (its "
        "word pair) from that frame; the repair re-verifies every code and reloads what fails before the next",
        ParityCode(2, FIELDS, diagonal=1, per_word=True),
        flags=False,  # 2 bits a primitive (a word pair at fp16/bf16: 1), nothing more: 0.45% of an SH-0 model
        label="2 diagonal parity bits in the frame",
    )
)
register(
    CellBox(
        "cellbox",
        "support boxes per spatial cell (8x8x8 grid, 9-bit cell id per primitive): clamp into its cell's box",
    )
)

register(
    SupportGuard(
        "guard_all",
        "the paper's Algorithm 1: clamp every value, sh_rest included, into the clean model's box",
        FIELDS,
        label="support guard, every field (paper)",
    )
)

DEFENSES = tuple(REGISTRY)
FIRST_DEFENSES = tuple(d.name for d in REGISTRY.values() if d.first_study)


def get(name: str) -> Defense:
    """The registered defense `name` (a clear error for any other name)."""
    return REGISTRY[checks.one_of(name, "defense", REGISTRY)]


def check_defense(name: str) -> str:
    return get(name).name


def partner_drop_refusal(what: str, defense: str, precision: str) -> str | None:
    """Why `what` (a measurement that draws one primitive a variant) cannot run under `defense` at
    `precision`, or None when it can (Defense.drops_partners): the one line the spec, the
    incremental evaluator and the worst-case search refuse with."""
    if not get(defense).drops_partners(precision):
        return None
    return (
        f"{what} under {defense} at {precision}: a detected upset drops its word partner too, which "
        "one-primitive variants do not draw; use fp32 or another defense"
    )


def defense_label(name: str) -> str:
    """The defense's short name in figures and tables (its name where it has none)."""
    d = REGISTRY.get(name)
    return d.label if d is not None else name


def pipeline_guards() -> dict[str, tuple[str, ...]]:
    """{name: fields} of the defenses whose fields the pipeline's support guard clamps."""
    return {d.name: d.guard_fields for d in REGISTRY.values() if d.guard_fields}


def guard_arm(ran) -> str | None:
    """The support-guard arm of a run's defenses (`ran`), the one its analyses set beside `none`:
    `guard` where it ran, else the first other pipeline guard in registry order (guard_all for a
    run that clamps every field); None where no guard ran."""
    ran = set(ran)
    return next((name for name in pipeline_guards() if name in ran), None)


def guard_arms(ran) -> tuple[str, ...]:
    """("none", the run's guard arm): each where it ran, in that order."""
    ran = set(ran)
    return tuple(d for d in ("none", guard_arm(ran)) if d is not None and d in ran)


def checked(name: str) -> CheckedDefense:
    """The registered defense `name`, which must have a per-primitive check."""
    d = get(name)
    if not d.checked:
        ok = ", ".join(x.name for x in REGISTRY.values() if x.checked)
        raise ValueError(f"defense {name!r} has no per-primitive check; checked ones: {ok}")
    return d


# ---- the twins by name (what the engine, the check stage and the tests call) -------------------
def side_data(defense: str, clean: np.ndarray, precision: str, degree: int, box=None) -> np.ndarray:
    """[M] u32 stored with each clean primitive by a checked defense (CheckedDefense.side_data)."""
    return checked(defense).side_data(np.asarray(clean), precision, degree, box)


def detect(defense: str, side: np.ndarray, rows: np.ndarray, precision: str, degree: int, box=None) -> np.ndarray:
    """[M] bool: the check of `defense` flags the primitive. Twin of shaders/check.wgsl."""
    return checked(defense).detect(side, np.asarray(rows), precision, degree, box)


def repair(defense: str, clean: np.ndarray, corrupt: np.ndarray, hit: np.ndarray, precision: str, box=None, side=None):
    return checked(defense).repair(np.asarray(clean), np.asarray(corrupt), hit, precision, box, side)


def read(
    defense: str, clean: np.ndarray, corrupt: np.ndarray, precision: str, degree: int, box=None, prims=None, cells=None
) -> np.ndarray:
    """What `defense` reads from primitives whose stored patterns went from `clean` to `corrupt`
    ([M, ncomp] each); `box` (faults/guard.Box of the clean model) is needed by scalebound, the
    primitives' indices and the model state (`Defense.model_state`, cellbox's CellBoxes) by cellbox."""
    return get(defense).read(np.asarray(clean), np.asarray(corrupt), precision, degree, box, prims, cells)
