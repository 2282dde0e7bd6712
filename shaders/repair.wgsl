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
// writes both halves and no two threads write one word.

override REPAIR_FLAGS: u32 = 1u;
override CODE_COVER: u32 = 0u;
override CODE_WAYS: u32 = 4u;
override CODE_DIAGONAL: u32 = 0u;

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
    let classes = parity_classes(CODE_WAYS, CODE_DIAGONAL);
    var x = 0u;
    for (var k = 0u; k < classes; k = k + 1u) {
        var acc = 0u;  // the class's stored words XORed, folded once (codes.wgsl parity_fold)
        for (var c = k; c < params.ncomp; c = c + classes) {
            acc = acc ^ words[c * params.plane_words + w];
        }
        x = parity_fold(x, stored_pattern(acc, j, params.fmt) & CODE_COVER, k, CODE_WAYS, CODE_DIAGONAL);
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
    var mask = 0u;  // the bits of the word to take from the golden copy
    for (var h = 0u; h < per; h = h + 1u) {
        let j = w * per + h;
        let p = params.prim_base + j;
        if (j >= params.chunk_count) {
            continue;
        }
        let code_word = code_word_index(p, CODE_WAYS);
        let stored_code = code_of(atomicLoad(&side[code_word]), p, CODE_WAYS);
        if (!needs_repair(w, j, p, stored_code)) {
            continue;
        }
        let half = select(0xffffu << (16u * h), 0xffffffffu, per == 1u);
        var s = CHECKSUM_SEED;
        var x = 0u;  // the golden row's code
        for (var c = 0u; c < params.ncomp; c = c + 1u) {
            let v = stored_pattern(golden[c * params.plane_words + w], j, params.fmt);
            s = checksum_step(s, v);
            x = parity_fold(x, v & CODE_COVER, c, CODE_WAYS, CODE_DIAGONAL);
        }
        if (s != golden_sum[p]) {
            atomicAdd(&out[OUT_FAULTS], 1u);
            continue;
        }
        let code = parity_code(x, CODE_WAYS);
        if (code != stored_code) {  // only this primitive's bits of the word change
            atomicXor(&side[code_word], (code ^ stored_code) << ((p % (32u / CODE_WAYS)) * CODE_WAYS));
        }
        mask = mask | half;
        if (REPAIR_FLAGS != 0u) {
            atomicAnd(&out[OUT_FLAGS + (p >> 5u)], ~(1u << (p & 31u)));
        }
        atomicAdd(&out[OUT_REPAIRED], 1u);
    }
    if (mask == 0u) {
        return;
    }
    for (var c = 0u; c < params.ncomp; c = c + 1u) {
        let i = c * params.plane_words + w;
        words[i] = (words[i] & ~mask) | (golden[i] & mask);
    }
}
