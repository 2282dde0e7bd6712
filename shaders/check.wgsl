// #import codes

// Per-primitive checks of the stored model (faults/check.py; twin: faults/defenses.py detect):
// recompute what each primitive stored beside the clean model (4 interleaved or 1 parity bit(s),
// a 32-bit checksum, or its scale class) from its words as they are now, flag mismatches
// and count them, so the host learns in one small read whether to repair. One thread per
// primitive of one chunk; the words are only read. The side data is packed as the memory
// column charges it (side_bits per primitive: side.pack_side), the flags one bit each.
//
// The checker's own state is checked too (issue 47): `seal` is a hash of every other parameter
// and of the table, computed by the host (check.py `seal_words`); the chunk's first thread
// recomputes it and counts a mismatch in `param_faults`, and the host then rewrites the
// parameters and checks again. The detection count is kept twice (`detected`, `detected_copy`):
// one upset in either cannot turn a non-zero count into zero.

struct CheckParams {
    plane_words: u32,
    ncomp: u32,
    chunk_count: u32,     // primitives in this chunk
    fmt: u32,             // FMT_FP32, FMT_FP16, FMT_BF16
    prim_base: u32,       // global index of this chunk's first primitive (side data, flags)
    mode: u32,            // MODE_PARITY, MODE_CHECKSUM, MODE_SCALE
    ways: u32,            // parity ways (1 or 4)
    cover: u32,           // bits of each value the parity covers
    comp_count: u32,      // parity covers components 0 .. comp_count - 1
    side_bits: u32,       // bits of side data per primitive (1, 4 or 32; side.pack_side)
    table_len: u32,       // f32 words of `table` the seal covers
    seal: u32,            // hash of the words above and of the table (check.py seal_words)
};

const MODE_PARITY: u32 = 0u;
const MODE_CHECKSUM: u32 = 1u;
const MODE_SCALE: u32 = 2u;

// laid out as codes.wgsl's OUT_* words (the host reads them by those names)
struct CheckOut {
    detected: atomic<u32>,
    detected_copy: atomic<u32>,  // the same count, kept twice
    param_faults: atomic<u32>,   // chunks whose parameters did not match their seal
    _p2: u32,
    flags: array<atomic<u32>>,   // bit g % 32 of word g / 32: primitive g (global index) flagged
};

@group(0) @binding(0) var<uniform> params: CheckParams;
@group(0) @binding(1) var<storage, read> side: array<u32>;
@group(0) @binding(2) var<storage, read> words: array<u32>;
@group(0) @binding(3) var<storage, read> table: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: CheckOut;

// stored pattern of component c of primitive j of this chunk
fn stored(j: u32, c: u32) -> u32 {
    return stored_pattern(words[stored_word_index(c, j, params.plane_words, params.fmt)], j, params.fmt);
}

// side code of primitive g (global index): side.unpack_side
fn side_code(g: u32) -> u32 {
    return code_of(side[code_word_index(g, params.side_bits)], g, params.side_bits);
}

// the parameters' seal as the host computed it (twin: check.py seal_words)
fn params_seal() -> u32 {
    var h = checksum_step(CHECKSUM_SEED, params.plane_words);
    h = checksum_step(h, params.ncomp);
    h = checksum_step(h, params.chunk_count);
    h = checksum_step(h, params.fmt);
    h = checksum_step(h, params.prim_base);
    h = checksum_step(h, params.mode);
    h = checksum_step(h, params.ways);
    h = checksum_step(h, params.cover);
    h = checksum_step(h, params.comp_count);
    h = checksum_step(h, params.side_bits);
    h = checksum_step(h, params.table_len);
    let n = min(params.table_len, arrayLength(&table));  // a flipped length never runs away
    for (var i = 0u; i < n; i = i + 1u) {
        h = checksum_step(h, bitcast<u32>(table[i]));
    }
    return h;
}

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    // thread 0 of every chunk exists whatever chunk_count says (the host sizes the dispatch)
    if (j == 0u && params_seal() != params.seal) {
        atomicAdd(&out.param_faults, 1u);
    }
    if (j >= params.chunk_count) {
        return;
    }
    var flagged = false;
    if (params.mode == MODE_PARITY) {
        // parity is linear: the XOR of the covered bits of every value, then one count per way
        var x = 0u;
        for (var c = 0u; c < params.comp_count; c = c + 1u) {
            x = x ^ (stored(j, c) & params.cover);
        }
        flagged = parity_code(x, params.ways) != side_code(params.prim_base + j);
    } else if (params.mode == MODE_CHECKSUM) {
        var h = CHECKSUM_SEED;
        for (var c = 0u; c < params.ncomp; c = c + 1u) {
            h = checksum_step(h, stored(j, c));
        }
        flagged = h != side_code(params.prim_base + j);
    } else if (params.mode == MODE_SCALE) {
        let bound = table[side_code(params.prim_base + j)];
        for (var c = 3u; c < 6u; c = c + 1u) {
            let w = words[stored_word_index(c, j, params.plane_words, params.fmt)];
            let v = decode_value(w, params.fmt != FMT_FP32 && (j & 1u) == 1u, params.fmt);
            if (!is_nan_f32(v) && v > bound) {  // NaN is the guard's (bit test, not v != v)
                flagged = true;
            }
        }
    }
    if (flagged) {
        let g = params.prim_base + j;
        atomicOr(&out.flags[g >> 5u], 1u << (g & 31u));
        atomicAdd(&out.detected, 1u);
        atomicAdd(&out.detected_copy, 1u);
    }
}
