// #import common

// The check codes on the device, one definition for the stages that compute them (twin:
// faults/codes.py): check.wgsl (every check defense), project.wgsl (the check inside the frame,
// FRAME_CHECK) and repair.wgsl (the golden row's checksum). Bindings differ between them, so the
// helpers take the words their caller read.

const CHECKSUM_SEED: u32 = 0x811C9DC5u;

// A check's output as words (check.wgsl's CheckOut, project.wgsl's frame_out, repair.wgsl's out;
// the host reads these names: faults/check.py CheckOutput): the detection count twice (an upset
// in one copy hides nothing), each check's own two words, then a flag bit per primitive.
const OUT_DETECTED: u32 = 0u;
const OUT_DETECTED_COPY: u32 = 1u;
const OUT_FAULTS: u32 = 2u;    // check.wgsl: parameter faults; repair.wgsl: golden rows that failed
const OUT_REPAIRED: u32 = 3u;  // repair.wgsl: primitives repaired
const OUT_FLAGS: u32 = 4u;     // the first flag word: primitive g is bit g % 32 of word OUT_FLAGS + g / 32

// MurmurHash3's finaliser: a bijection of u32 that avalanches (twin: codes.fmix32)
fn fmix32(x: u32) -> u32 {
    var h = x ^ (x >> 16u);
    h = h * 0x85ebca6bu;
    h = h ^ (h >> 13u);
    h = h * 0xc2b2ae35u;
    return h ^ (h >> 16u);
}

// one step of the checksum (codes.checksum): h = fmix32(h ^ value)
fn checksum_step(h: u32, value: u32) -> u32 {
    return fmix32(h ^ value);
}

// index of the stored word holding component c of primitive j of a chunk (planar layout: a
// plane of plane_words words per component; two 16-bit values a word at fp16/bf16)
fn stored_word_index(c: u32, j: u32, plane_words: u32, fmt: u32) -> u32 {
    return c * plane_words + select(j >> 1u, j, fmt == FMT_FP32);
}

// primitive j's stored pattern in its word (the whole word at fp32, its half otherwise)
fn stored_pattern(word: u32, j: u32, fmt: u32) -> u32 {
    if (fmt == FMT_FP32) {
        return word;
    }
    return (word >> (16u * (j & 1u))) & 0xffffu;
}

// what a code folds of a stored word: primitive j's pattern, or with a per-word code (per_word:
// codes.ParityCode.pairs, set by the host at fp16/bf16 only) the whole word, both primitives of
// the pair (2i, 2i + 1) it holds (the cover mask then covers both halves)
fn coded_pattern(word: u32, j: u32, fmt: u32, per_word: u32) -> u32 {
    if (per_word != 0u) {
        return word;
    }
    return stored_pattern(word, j, fmt);
}

// the index of primitive p's code in the side data: p, or with a per-word code its pair's, p >> 1
// (chunks start at even primitives, fields.StoredLayout: the pair of word j >> 1 of a chunk)
fn code_index(p: u32, per_word: u32) -> u32 {
    return select(p, p >> 1u, per_word != 0u);
}

// the parity code of x, the XOR of a primitive's covered bits (parity_fold): one parity bit per
// way, way w over the bit positions b with b % ways == w (ways 1, 2, 4, 8; 1 way: every bit)
// (codes.ParityCode.code)
fn parity_code(x: u32, ways: u32) -> u32 {
    var par = 0u;
    for (var w = 0u; w < ways; w = w + 1u) {
        let way = (0xffffffffu / ((1u << ways) - 1u)) << w;
        par = par | ((countOneBits(x & way) & 1u) << w);
    }
    return par;
}

// x with value c's covered bits folded in, rotated left by (diagonal c) % ways so that its bit b
// counts in way (b + diagonal c) % ways (diagonal 0: by bit position alone, parity4r's code).
fn parity_fold(x: u32, covered: u32, c: u32, ways: u32, diagonal: u32) -> u32 {
    let k = (c * diagonal) % ways;
    return x ^ ((covered << k) | (covered >> ((32u - k) & 31u)));
}

// the side data word holding primitive g's code of `bits` bits (side.pack_side)
fn code_word_index(g: u32, bits: u32) -> u32 {
    return g / (32u / bits);
}

// primitive g's code in its side data word (side.unpack_side)
fn code_of(word: u32, g: u32, bits: u32) -> u32 {
    if (bits == 32u) {
        return word;
    }
    let per = 32u / bits;
    return (word >> ((g % per) * bits)) & ((1u << bits) - 1u);
}
