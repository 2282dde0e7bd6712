// Support guard, scrub mode: clamp every guarded stored value of one model chunk into the clean
// model's box, rewriting the stored bits (the bounds' own stored bits, so the result is exactly a
// value of the clean model's range), and count clamps per field and per primitive.
// One thread per stored word of one component plane (a word holds 1 or 2 primitives).

struct GuardParams {
    plane_words: u32,
    ncomp: u32,
    chunk_count: u32,     // primitives in this chunk
    fmt: u32,             // 0 fp32, 1 fp16, 2 bf16
    mask_lo: u32,         // guarded components 0..31
    mask_hi: u32,         // guarded components 32..63
    prim_base: u32,       // offset of this chunk's primitives in the per-primitive counters
    _p: u32,
};

struct Bound {
    lo: f32,
    hi: f32,
    lo_bits: u32,         // stored bits of lo (fp32 word or 16-bit half)
    hi_bits: u32,
};

@group(0) @binding(0) var<uniform> params: GuardParams;
@group(0) @binding(1) var<storage, read> box: array<Bound>;
@group(0) @binding(2) var<storage, read_write> words: array<u32>;
// [0..8): clamps per field; [8 + prim_base + j]: clamps of primitive j of this chunk
@group(0) @binding(3) var<storage, read_write> counts: array<atomic<u32>>;

fn guarded(c: u32) -> bool {
    if (c < 32u) {
        return ((params.mask_lo >> c) & 1u) == 1u;
    }
    return ((params.mask_hi >> (c - 32u)) & 1u) == 1u;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = gid.x + gid.y * nwg.x * 256u;
    let c = t / params.plane_words;
    let w = t % params.plane_words;
    if (c >= params.ncomp || !guarded(c)) {
        return;
    }
    let b = box[c];
    let field = field_of(c);
    var word = words[t];
    var n_clamped = 0u;
    if (params.fmt == 0u) {
        if (w >= params.chunk_count) {
            return;
        }
        let side = guard_side(bitcast<f32>(word), b.lo, b.hi);
        if (side != 0u) {
            word = select(b.hi_bits, b.lo_bits, side == 1u);
            atomicAdd(&counts[8u + params.prim_base + w], 1u);
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
                atomicAdd(&counts[8u + params.prim_base + j], 1u);
                n_clamped = n_clamped + 1u;
            }
        }
    }
    if (n_clamped > 0u) {
        words[t] = word;
        atomicAdd(&counts[field], n_clamped);
    }
}
