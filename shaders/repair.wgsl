// #import codes

// Repair on the device (faults/check.py DeviceRepair): every primitive the check inside the frame
// found failing (project.wgsl FRAME_CHECK) is rewritten from the golden copy of its chunk, after the
// golden row's own checksum is verified (h = fmix32(h ^ value) over its values, as check.wgsl's
// MODE_CHECKSUM); a golden row that fails is counted and left alone (the primitive stays dropped).
// Which primitives failed: with REPAIR_FLAGS, the flag bits the frame set; without (a code that
// keeps no flags), this pass recomputes every primitive's code (CODE_*: the frame check's
// FRAME_COVER, FRAME_WAYS, FRAME_DIAGONAL) from its stored words against the stored `side`.
// A repaired primitive's code is rewritten too where the verified golden row's code differs from
// the stored one: an upset in the code bits (which makes a clean primitive fail every frame) is
// repaired by the same pass, not left to fail until the side data is reloaded.
// One thread per stored word of a plane: at fp16/bf16 a word holds two primitives, so one thread
// writes both halves and no two threads write one word. CODE_PER_WORD (fp16/bf16 only: a per-word
// code, parity2f's): one code covers the word's two primitives, verified once; a word that fails is
// rewritten whole once both golden rows pass their checksums (either failing: counted, the word
// left alone), and its code rewritten from the golden words.

override REPAIR_FLAGS: u32 = 1u;
override CODE_COVER: u32 = 0u;
override CODE_WAYS: u32 = 4u;
override CODE_DIAGONAL: u32 = 0u;
override CODE_PER_WORD: u32 = 0u;

struct RepairParams {
    plane_words: u32,
    ncomp: u32,
    chunk_count: u32,     // primitives in this chunk
    fmt: u32,
    prim_base: u32,       // global index of this chunk's first primitive
    _p0: u32,
    _p1: u32,
    _p2: u32,
};

@group(0) @binding(0) var<uniform> params: RepairParams;
@group(0) @binding(1) var<storage, read_write> words: array<u32>;
@group(0) @binding(2) var<storage, read> golden: array<u32>;
@group(0) @binding(3) var<storage, read> golden_sum: array<u32>;
// the frame check's output, laid out as codes.wgsl's OUT_* words: the detections, the golden rows
// that failed (OUT_FAULTS), the primitives repaired (OUT_REPAIRED), the flags (cleared when repaired)
@group(0) @binding(4) var<storage, read_write> out: array<atomic<u32>>;
// the frame check's packed codes: read without REPAIR_FLAGS, a repaired primitive's rewritten
// (atomically: a word holds the codes of 32 / CODE_WAYS primitives, of other threads)
@group(0) @binding(5) var<storage, read_write> side: array<atomic<u32>>;

// primitive j (global p) of stored word w needs a repair: flagged, or its code fails
fn needs_repair(w: u32, j: u32, p: u32, stored_code: u32) -> bool {
    if (REPAIR_FLAGS != 0u) {
        return (atomicLoad(&out[OUT_FLAGS + (p >> 5u)]) & (1u << (p & 31u))) != 0u;
    }
    var x = 0u;
    for (var c = 0u; c < params.ncomp; c = c + 1u) {
        let v = coded_pattern(words[c * params.plane_words + w], j, params.fmt, CODE_PER_WORD);
        x = parity_fold(x, v & CODE_COVER, c, CODE_WAYS, CODE_DIAGONAL);
    }
    return parity_code(x, CODE_WAYS) != stored_code;
}

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let w = linear_id(gid, nwg);
    let per = select(2u, 1u, params.fmt == FMT_FP32);
    if (w * per >= params.chunk_count) {
        return;
    }
    let codes = select(per, 1u, CODE_PER_WORD != 0u);  // codes of this word: one a primitive, or one
    let span = per / codes;  // primitives a code covers (2: a per-word code)
    var mask = 0u;  // the bits of the word to take from the golden copy
    for (var h = 0u; h < codes; h = h + 1u) {
        let j = w * per + h;  // the code's first primitive (a per-word code's: the word's even one)
        let p = params.prim_base + j;
        if (j >= params.chunk_count) {
            continue;
        }
        let q = code_index(p, CODE_PER_WORD);
        let code_word = code_word_index(q, CODE_WAYS);
        let stored_code = code_of(atomicLoad(&side[code_word]), q, CODE_WAYS);
        if (!needs_repair(w, j, p, stored_code)) {
            continue;
        }
        let part = select(0xffffu << (16u * h), 0xffffffffu, span == per);  // the code's bits of the word
        var x = 0u;  // the golden words' code
        for (var c = 0u; c < params.ncomp; c = c + 1u) {
            let v = coded_pattern(golden[c * params.plane_words + w], j, params.fmt, CODE_PER_WORD);
            x = parity_fold(x, v & CODE_COVER, c, CODE_WAYS, CODE_DIAGONAL);
        }
        var rows = 0u;  // the code's primitives, each golden row's checksum verified
        var failed = 0u;
        for (var i = 0u; i < span; i = i + 1u) {
            let jj = j + i;
            if (jj >= params.chunk_count) {
                break;
            }
            var s = CHECKSUM_SEED;
            for (var c = 0u; c < params.ncomp; c = c + 1u) {
                s = checksum_step(s, stored_pattern(golden[c * params.plane_words + w], jj, params.fmt));
            }
            rows = rows + 1u;
            failed = failed + select(0u, 1u, s != golden_sum[params.prim_base + jj]);
        }
        if (failed != 0u) {
            atomicAdd(&out[OUT_FAULTS], failed);
            continue;
        }
        let code = parity_code(x, CODE_WAYS);
        if (code != stored_code) {  // only this code's bits of the side word change
            atomicXor(&side[code_word], (code ^ stored_code) << ((q % (32u / CODE_WAYS)) * CODE_WAYS));
        }
        mask = mask | part;
        if (REPAIR_FLAGS != 0u) {
            atomicAnd(&out[OUT_FLAGS + (p >> 5u)], ~(1u << (p & 31u)));
        }
        atomicAdd(&out[OUT_REPAIRED], rows);
    }
    if (mask == 0u) {
        return;
    }
    for (var c = 0u; c < params.ncomp; c = c + 1u) {
        let i = c * params.plane_words + w;
        words[i] = (words[i] & ~mask) | (golden[i] & mask);
    }
}
