// Support guard, scrub mode (faults/guard.py scrub; twin: clamp_bits): clamp every guarded stored value of one model chunk into the clean
// model's box, rewriting the stored bits (the bounds' own stored bits, so the result is exactly a
// value of the clean model's range), and count clamps per field and per primitive.
// One thread per stored word of one component plane (a word holds 1 or 2 primitives).

struct GuardParams {
    plane_words: u32,
    ncomp: u32,
    chunk_count: u32,     // primitives in this chunk
    fmt: u32,             // FMT_FP32, FMT_FP16, FMT_BF16
    mask_lo: u32,         // guarded components 0..31
    mask_hi: u32,         // guarded components 32..63
    prim_base: u32,       // offset of this chunk's primitives in the per-primitive counters
    _p: u32,
};

@group(0) @binding(0) var<uniform> params: GuardParams;
@group(0) @binding(1) var<storage, read> box: array<Bound>;
@group(0) @binding(2) var<storage, read_write> words: array<u32>;
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

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = linear_id(gid, nwg);
    let c = t / params.plane_words;
    let w = t % params.plane_words;
    if (c >= params.ncomp || !guarded(c)) {
        return;
    }
    let b = box[c];
    let field = field_of(c);
    var word = words[t];
    var n_clamped = 0u;
    if (params.fmt == FMT_FP32) {
        if (w >= params.chunk_count) {
            return;
        }
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
            let v = decode_value(word, h == 1u, params.fmt);
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
    if (n_clamped > 0u) {
        words[t] = word;
        atomicAdd(&counts.per_field[field], n_clamped);
    }
}
