// Stable LSD radix sort of (u32 key, u32 value) pairs, 4 bits per pass (seuwgpu/gpu/sort.py).
//
// Per pass: `rs_upsweep` counts the digits of each block of 4096 elements (256 threads x 16
// contiguous elements) into hist[digit * blocks + block]; PrefixSum scans that digit-major array,
// so hist[d * blocks + b] becomes the output position of block b's first element with digit d;
// `rs_scatter` recounts its block, scans the per-thread digit counts over the workgroup and writes
// each thread's run in order. Threads own contiguous runs, so equal keys keep their input order
// (stable) and no inter-workgroup communication is needed (no forward-progress assumption).
//
// Per-thread digit counts are packed two digits per u32 (16-bit fields; a block has at most 4096
// elements of one digit, so fields never carry into each other).
//
// Arrays larger than one storage binding: inputs are read chunk by chunk (one dispatch per chunk,
// bound at the chunk's offset), outputs are bound as two halves split at `rs_pass.split`.
// Workgroup memory is written before it is read (lavapipe does not zero it).

const RS_PER: u32 = 16u;
const RS_BLOCK: u32 = 4096u;
const RS_MAX_X: u32 = 32768u;
// Plan buffer layout (u32 words): [0] count, [1] blocks, [2] 16 * blocks (the scan's count),
// [4 + 3c ..) indirect args of chunk c.
const RS_ARGS: u32 = 4u;

struct RsPass {
    shift: u32,   // digit = (key >> shift) & mask
    mask: u32,
    block0: u32,  // first block of the chunk bound to this dispatch
    bpc: u32,     // blocks per chunk
    split: u32,   // outputs: index < split goes to *_lo, the rest to *_hi
    _p0: u32,
    _p1: u32,
    _p2: u32,
};

struct RsPlanArgs {
    word: u32,   // index of the count in rs_count
    limit: u32,  // the count is clamped to this (capacity, caller buffer sizes)
    chunk: u32,  // elements per chunk (a multiple of RS_BLOCK)
    nch: u32,    // chunks
};

// Inputs are read as vec4 (one load per 4 elements: lavapipe issues memory accesses lane by lane,
// so their number is what costs); buffer sizes are multiples of 16 bytes.
@group(0) @binding(0) var<storage, read> rs_keys_in: array<vec4<u32>>;
@group(0) @binding(1) var<storage, read> rs_vals_in: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> rs_keys_lo: array<u32>;
@group(0) @binding(3) var<storage, read_write> rs_keys_hi: array<u32>;
@group(0) @binding(4) var<storage, read_write> rs_vals_lo: array<u32>;
@group(0) @binding(5) var<storage, read_write> rs_vals_hi: array<u32>;
@group(0) @binding(6) var<storage, read> rs_hist: array<u32>;
@group(0) @binding(7) var<storage, read_write> rs_hist_w: array<u32>;
@group(0) @binding(8) var<storage, read> rs_plan: array<u32>;
@group(0) @binding(9) var<storage, read_write> rs_plan_w: array<u32>;
@group(0) @binding(10) var<storage, read> rs_count: array<u32>;
@group(0) @binding(11) var<uniform> rs_pargs: RsPlanArgs;
@group(1) @binding(0) var<uniform> rs_pass: RsPass;

var<workgroup> rs_cnt: array<u32, 2048>;   // [digit pair][thread] packed counts
var<workgroup> rs_part: array<u32, 128>;   // [digit pair][16 thread groups]
var<workgroup> rs_base: array<u32, 16>;    // scanned hist of this block, per digit
var<private> rs_k: array<u32, 16>;

@compute @workgroup_size(1)
fn rs_plan_main() {
    let n = min(rs_count[rs_pargs.word], rs_pargs.limit);
    let nb = (n + RS_BLOCK - 1u) / RS_BLOCK;
    rs_plan_w[0] = n;
    rs_plan_w[1] = nb;
    rs_plan_w[2] = nb * 16u;
    rs_plan_w[3] = 0u;
    let bpc = rs_pargs.chunk / RS_BLOCK;
    for (var c = 0u; c < rs_pargs.nch; c++) {
        var groups = 0u;
        if (nb > c * bpc) {
            groups = min(nb - c * bpc, bpc);
        }
        var d = vec3<u32>(groups, 1u, 1u);
        if (groups > RS_MAX_X) {
            d = vec3<u32>(RS_MAX_X, (groups + RS_MAX_X - 1u) / RS_MAX_X, 1u);
        }
        let a = RS_ARGS + 3u * c;
        rs_plan_w[a] = d.x;
        rs_plan_w[a + 1u] = d.y;
        rs_plan_w[a + 2u] = d.z;
    }
}

// Number of valid workgroups of this chunk's dispatch (the 2-D grid may have a few extra).
fn rs_groups(nb: u32) -> u32 {
    if (nb <= rs_pass.block0) {
        return 0u;
    }
    return min(nb - rs_pass.block0, rs_pass.bpc);
}

// Loads the thread's run of keys into rs_k and writes its packed digit counts to rs_cnt.
fn rs_count_run(t: u32, lbase: u32, gbase: u32, n: u32) {
    var c0 = vec4<u32>(0u);
    var c1 = vec4<u32>(0u);
    let sel0 = vec4<u32>(0u, 1u, 2u, 3u);
    let sel1 = vec4<u32>(4u, 5u, 6u, 7u);
    for (var j = 0u; j < RS_PER / 4u; j++) {
        if (gbase + 4u * j < n) {
            let k4 = rs_keys_in[(lbase >> 2u) + j];
            for (var i = 0u; i < 4u; i++) {
                let k = 4u * j + i;
                let key = k4[i];
                rs_k[k] = key;
                if (gbase + k < n) {
                    let d = (key >> rs_pass.shift) & rs_pass.mask;
                    let inc = vec4<u32>(1u << ((d & 1u) << 4u));
                    let w = vec4<u32>(d >> 1u);
                    c0 += select(vec4<u32>(0u), inc, w == sel0);
                    c1 += select(vec4<u32>(0u), inc, w == sel1);
                }
            }
        }
    }
    rs_cnt[t] = c0.x;
    rs_cnt[256u + t] = c0.y;
    rs_cnt[512u + t] = c0.z;
    rs_cnt[768u + t] = c0.w;
    rs_cnt[1024u + t] = c1.x;
    rs_cnt[1280u + t] = c1.y;
    rs_cnt[1536u + t] = c1.z;
    rs_cnt[1792u + t] = c1.w;
}

@compute @workgroup_size(256)
fn rs_upsweep(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = rs_plan[0];
    let nb = rs_plan[1];
    if (wid >= rs_groups(nb)) {
        return;
    }
    let lbase = wid * RS_BLOCK + t * RS_PER;
    let gbase = rs_pass.block0 * RS_BLOCK + lbase;
    rs_count_run(t, lbase, gbase, n);
    workgroupBarrier();
    if (t < 128u) {
        // pair w = t / 16, thread group g = t % 16
        let b = (t >> 4u) * 256u + (t & 15u) * 16u;
        var acc = 0u;
        for (var k = 0u; k < 16u; k++) {
            acc += rs_cnt[b + k];
        }
        rs_part[t] = acc;
    }
    workgroupBarrier();
    if (t < 16u) {
        let w = t >> 1u;
        var acc = 0u;
        for (var g = 0u; g < 16u; g++) {
            acc += rs_part[w * 16u + g];
        }
        rs_hist_w[t * nb + rs_pass.block0 + wid] = (acc >> ((t & 1u) << 4u)) & 0xffffu;
    }
}

@compute @workgroup_size(256)
fn rs_scatter(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = rs_plan[0];
    let nb = rs_plan[1];
    if (wid >= rs_groups(nb)) {
        return;
    }
    let block = rs_pass.block0 + wid;
    let lbase = wid * RS_BLOCK + t * RS_PER;
    let gbase = block * RS_BLOCK + t * RS_PER;
    rs_count_run(t, lbase, gbase, n);
    if (t < 16u) {
        rs_base[t] = rs_hist[t * nb + block];
    }
    workgroupBarrier();
    // Exclusive scan of the packed counts over threads, per digit pair: 128 threads scan 16
    // threads' counts each, then 8 threads scan the 16 group sums of their pair.
    if (t < 128u) {
        let b = (t >> 4u) * 256u + (t & 15u) * 16u;
        var acc = 0u;
        for (var k = 0u; k < 16u; k++) {
            let x = rs_cnt[b + k];
            rs_cnt[b + k] = acc;
            acc += x;
        }
        rs_part[t] = acc;
    }
    workgroupBarrier();
    if (t < 8u) {
        var acc = 0u;
        for (var g = 0u; g < 16u; g++) {
            let x = rs_part[t * 16u + g];
            rs_part[t * 16u + g] = acc;
            acc += x;
        }
    }
    workgroupBarrier();
    // Running packed offsets of this thread, kept in its own rs_cnt slots (no races).
    let grp = t >> 4u;
    for (var w = 0u; w < 8u; w++) {
        rs_cnt[w * 256u + t] += rs_part[w * 16u + grp];
    }
    let split = rs_pass.split;
    for (var j = 0u; j < RS_PER / 4u; j++) {
        if (gbase + 4u * j >= n) {
            break;
        }
        let v4 = rs_vals_in[(lbase >> 2u) + j];
        for (var e = 0u; e < 4u; e++) {
            let k = 4u * j + e;
            if (gbase + k < n) {
                let key = rs_k[k];
                let d = (key >> rs_pass.shift) & rs_pass.mask;
                let s = (d & 1u) << 4u;
                let slot = (d >> 1u) * 256u + t;
                let o = rs_cnt[slot];
                rs_cnt[slot] = o + (1u << s);
                let dst = rs_base[d] + ((o >> s) & 0xffffu);
                if (dst < split) {
                    rs_keys_lo[dst] = key;
                    rs_vals_lo[dst] = v4[e];
                } else {
                    rs_keys_hi[dst - split] = key;
                    rs_vals_hi[dst - split] = v4[e];
                }
            }
        }
    }
}

// Copies count pairs from the inputs to the *_lo outputs (both bound at the chunk's offset): an
// odd number of passes starts from the internal buffers so that the result ends in the caller's.
@group(0) @binding(12) var<storage, read_write> rs_keys_lo4: array<vec4<u32>>;
@group(0) @binding(13) var<storage, read_write> rs_vals_lo4: array<vec4<u32>>;

@compute @workgroup_size(256)
fn rs_copy(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = rs_plan[0];
    if (wid >= rs_groups(rs_plan[1])) {
        return;
    }
    // vec4 granularity: a partial last vec4 is copied whole (the destination is internal).
    let g0 = (rs_pass.block0 + wid) * (RS_BLOCK / 4u);
    for (var k = 0u; k < RS_PER / 4u; k++) {
        let l = wid * (RS_BLOCK / 4u) + k * 256u + t;
        if (4u * (g0 + k * 256u + t) < n) {
            rs_keys_lo4[l] = rs_keys_in[l];
            rs_vals_lo4[l] = rs_vals_in[l];
        }
    }
}
