// #import common

// Support guard, scrub mode (faults/guard.py scrub; twin: clamp_bits): clamp every guarded stored value of one model chunk into the clean
// model's box, rewriting the stored bits (the bounds' own stored bits, so the result is exactly a
// value of the clean model's range), and count clamps per field and per primitive.
// One thread per stored word of one component plane (a word holds 1 or 2 primitives).

// Specialised per stored precision (override FMT; faults/guard.py picks the pipeline from the
// slot's `fmt`). Each thread scrubs WPT consecutive words of one guarded component's plane, and
// the host dispatches only the planes from the first to the last guarded component; a branch-free
// integer range test on the raw bits clears clean words, and only a thread holding a value
// that may be outside takes the exact per-value path. A scrub thus reads the guarded planes once
// and writes only clamped words.
override FMT: u32 = 0u;
override WPT: u32 = 4u;  // words per thread (faults/guard.py: many on CPU adapters, where each
                         // invocation and workgroup has a fixed cost; 4 on GPUs)

struct GuardParams {
    plane_words: u32,
    ncomp: u32,
    chunk_count: u32,     // primitives in this chunk
    fmt: u32,             // = FMT of the pipeline that reads this slot
    mask_lo: u32,         // guarded components 0..31
    mask_hi: u32,         // guarded components 32..63
    prim_base: u32,       // offset of this chunk's primitives in the per-primitive counters
    comp_first: u32,      // first guarded component: thread 0 starts on its plane
};

@group(0) @binding(0) var<uniform> params: GuardParams;
@group(0) @binding(1) var<storage, read> box: array<Bound>;
@group(0) @binding(2) var<storage, read_write> words: array<vec4<u32>>;  // the chunk's words, 4 per element

fn word_at(i: u32) -> u32 {
    return words[i >> 2u][i & 3u];
}
// Clamp counters: per field, and per primitive (primitive j of this chunk at prim_base + j).
struct ClampCounts {
    per_field: array<atomic<u32>, 8>,
    per_primitive: array<atomic<u32>>,
};

@group(0) @binding(3) var<storage, read_write> counts: ClampCounts;

fn guarded(c: u32) -> bool {
    if (c < 32u) {
        return ((params.mask_lo >> c) & 1u) == 1u;
    }
    return ((params.mask_hi >> (c - 32u)) & 1u) == 1u;
}

// One stored word of component plane c (bounds b): the word with its guarded values clamped, and
// how many were clamped (per-primitive counters updated); w is the word's index in the plane.
fn scrub_word(word0: u32, w: u32, b: Bound) -> vec2<u32> {
    var word = word0;
    var n_clamped = 0u;
    if (FMT == FMT_FP32) {
        let side = guard_side(bitcast<f32>(word), b.lo, b.hi);
        if (side != 0u) {
            word = select(b.hi_bits, b.lo_bits, side == 1u);
            atomicAdd(&counts.per_primitive[params.prim_base + w], 1u);
            n_clamped = 1u;
        }
    } else {
        for (var h = 0u; h < 2u; h = h + 1u) {
            let j = 2u * w + h;
            if (j >= params.chunk_count) {
                break;
            }
            let v = decode_value(word, h == 1u, FMT);
            let side = guard_side(v, b.lo, b.hi);
            if (side != 0u) {
                let nb = select(b.hi_bits, b.lo_bits, side == 1u) & 0xffffu;
                let shift = 16u * h;
                word = (word & ~(0xffffu << shift)) | (nb << shift);
                atomicAdd(&counts.per_primitive[params.prim_base + j], 1u);
                n_clamped = n_clamped + 1u;
            }
        }
    }
    return vec2<u32>(word, n_clamped);
}

// Order-preserving integer key of a stored value's bits (sign bit `sign`: 0x80000000 for fp32,
// 0x8000 for 16-bit): a < b as numbers iff key(a) < key(b), for non-NaN values other than
// -0 vs +0; NaNs land beyond both infinities.
fn order_key(bits: u32, sign: u32) -> u32 {
    return select(bits | sign, ~bits & (sign | (sign - 1u)), (bits & sign) != 0u);
}

// Key range [lo, hi] of a box's stored bounds (a zero bound widened to both zeros): a value whose
// key lies inside is inside the box (guard_side 0), exactly; anything else takes the exact path.
fn key_range(b: Bound, sign: u32) -> vec2<u32> {
    let mag = sign - 1u;
    var lo = b.lo_bits & (sign | mag);
    var hi = b.hi_bits & (sign | mag);
    if ((lo & mag) == 0u) { lo = sign; }   // -0
    if ((hi & mag) == 0u) { hi = 0u; }     // +0
    return vec2<u32>(order_key(lo, sign), order_key(hi, sign));
}

fn order_key4(bits: vec4<u32>, sign: u32) -> vec4<u32> {
    let full = vec4<u32>(sign | (sign - 1u));
    return select(bits | vec4<u32>(sign), ~bits & full, (bits & vec4<u32>(sign)) != vec4<u32>(0u));
}

// Whether any value of words [w0, w1) of plane c may lie outside the box: integer compares on
// the raw bits, no branch per value (the common case of a scrub is a clean plane); 4 words per
// read where the words are 16-byte aligned.
fn any_outside(c: u32, w0: u32, w1: u32, b: Bound) -> bool {
    let sign = select(0x8000u, 0x80000000u, FMT == FMT_FP32);
    let r = key_range(b, sign);
    let lo = vec4<u32>(r.x);
    let hi = vec4<u32>(r.y);
    let i0 = c * params.plane_words + w0;
    let i1 = i0 + (w1 - w0);
    var out = vec4<bool>(false);
    for (var i = i0 & ~3u; i < i1; i = i + 4u) {
        let x = words[i >> 2u];
        let idx = vec4<u32>(i) + vec4<u32>(0u, 1u, 2u, 3u);
        let valid = (idx >= vec4<u32>(i0)) & (idx < vec4<u32>(i1));
        if (FMT == FMT_FP32) {
            let k = order_key4(x, sign);
            out = out | (valid & ((k < lo) | (k > hi)));
        } else {
            let k0 = order_key4(x & vec4<u32>(0xffffu), sign);
            let k1 = order_key4(x >> vec4<u32>(16u), sign);
            out = out | (valid & ((k0 < lo) | (k0 > hi) | (k1 < lo) | (k1 > hi)));
        }
    }
    return any(out);
}

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = linear_id(gid, nwg);
    let per_plane = (params.plane_words + WPT - 1u) / WPT;
    let c = params.comp_first + t / per_plane;
    if (c >= params.ncomp || !guarded(c)) {
        return;
    }
    let b = box[c];
    // words of the plane holding primitives (fp32: one each; 16-bit formats: two each)
    var used = params.chunk_count;
    if (FMT != FMT_FP32) {
        used = (params.chunk_count + 1u) / 2u;
    }
    let w0 = (t % per_plane) * WPT;
    let w1 = min(w0 + WPT, used);
    if (!any_outside(c, w0, w1, b)) {
        return;
    }
    var n_clamped = 0u;
    for (var w = w0; w < w1; w = w + 1u) {
        let i = c * params.plane_words + w;
        let r = scrub_word(word_at(i), w, b);
        if (r.y > 0u) {
            words[i >> 2u][i & 3u] = r.x;
            n_clamped = n_clamped + r.y;
        }
    }
    if (n_clamped > 0u) {
        atomicAdd(&counts.per_field[field_of(c)], n_clamped);
    }
}
