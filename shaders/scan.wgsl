// #import common

// Exclusive prefix sum of u32 (seuwgpu/gpu/sort.py: PrefixSum), reduce-then-scan.
//
// A block is WG (256) threads x PS_PER elements; each thread owns PS_PER contiguous elements. Levels: the
// data (level 0) is reduced to one sum per block (level 1), and so on until a level fits one
// block; that level is scanned by a single workgroup ("top"), then each lower level is scanned
// block by block with its block's offset from the level above ("downsweep"). No inter-workgroup
// communication inside a dispatch, so no forward-progress assumption.
//
// Counts are dynamic: `ps_plan_main` turns a count read from a buffer into per-level counts and
// indirect dispatch arguments (a 2-D grid when a level has more than MAX_GROUPS_X blocks). Arrays larger
// than one storage binding are processed in chunks: every block kernel is dispatched once per
// chunk, with its arrays bound at the chunk's offset and the chunk's first block in `ps_pass`.
//
// Data is read and written as vec4 (lavapipe performs each memory access lane by lane, so their
// number is what costs): buffer sizes must be multiples of 16 bytes (GPU.buffer rounds them up).
// A vec4 straddling the count is written back with its elements past the count unchanged.
// Workgroup memory is written before it is read (lavapipe does not zero it).

// Elements per thread, a multiple of 4 (sort.py: 64 on CPU adapters, where each workgroup barrier
// costs several microseconds, 16 on GPUs, for occupancy).
override PS_PER: u32 = 16u;
override PS_BLOCK: u32 = WG * PS_PER;
// Workgroups per dispatch row; larger grids are 2-D (overridable so that tests reach that path).
override PS_MAX_X: u32 = MAX_GROUPS_X;
// Plan buffer layout (u32 words, PS_TOTAL and PS_ARGS from sort.py's SCAN_PLAN): [0..4) count
// per level, [PS_TOTAL] total, [PS_ARGS + 3k ..) indirect args of dispatch slot k.

struct PsPass {
    level: u32,   // plan slot holding this level's element count
    block0: u32,  // first block of the chunk bound to this dispatch
    bpc: u32,     // blocks per chunk
    _pad: u32,
};

struct PsPlanArgs {
    word: u32,      // index of the count in ps_count
    limit: u32,     // the count is clamped to this (capacity, caller buffer sizes)
    capacity: u32,  // static capacity of level 0 (fixes the number of levels and chunks)
    chunk: u32,     // elements per chunk (a multiple of PS_BLOCK)
};

@group(0) @binding(0) var<storage, read> ps_src: array<vec4<u32>>;
@group(0) @binding(1) var<storage, read_write> ps_dst: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> ps_offs: array<u32>;       // scanned block sums, level + 1
@group(0) @binding(3) var<storage, read_write> ps_sums: array<u32>; // block sums out, level + 1
@group(0) @binding(4) var<storage, read> ps_plan: array<u32>;
@group(0) @binding(5) var<storage, read_write> ps_plan_w: array<u32>;
@group(0) @binding(6) var<storage, read> ps_count: array<u32>;
@group(0) @binding(7) var<uniform> ps_pargs: PsPlanArgs;
// This dispatch's slot of the scan's pass table (bound at an offset, with the arrays).
@group(0) @binding(8) var<uniform> ps_pass: PsPass;

var<workgroup> ps_sh: array<u32, WG>;
var<workgroup> ps_part: array<u32, 17>;

fn ps_dims(groups: u32) -> vec3<u32> {
    if (groups <= PS_MAX_X) {
        return vec3<u32>(groups, 1u, 1u);
    }
    return vec3<u32>(PS_MAX_X, (groups + PS_MAX_X - 1u) / PS_MAX_X, 1u);
}

// One thread: the count -> per-level counts and the indirect arguments of every (level, chunk)
// dispatch, in the order sort.py issues them.
@compute @workgroup_size(1)
fn ps_plan_main() {
    var n = min(ps_count[ps_pargs.word], ps_pargs.limit);
    var cap = ps_pargs.capacity;
    let bpc = ps_pargs.chunk / PS_BLOCK;
    var slot = 0u;
    for (var l = 0u; l < 4u; l++) {
        ps_plan_w[l] = n;
        if (cap <= PS_BLOCK) {
            break;
        }
        let nb = (n + PS_BLOCK - 1u) / PS_BLOCK;
        let cap_b = (cap + PS_BLOCK - 1u) / PS_BLOCK;
        let nch = (cap_b + bpc - 1u) / bpc;
        for (var c = 0u; c < nch; c++) {
            var groups = 0u;
            if (nb > c * bpc) {
                groups = min(nb - c * bpc, bpc);
            }
            let d = ps_dims(groups);
            let a = PS_ARGS + 3u * slot;
            ps_plan_w[a] = d.x;
            ps_plan_w[a + 1u] = d.y;
            ps_plan_w[a + 2u] = d.z;
            slot += 1u;
        }
        n = nb;
        cap = cap_b;
    }
    ps_plan_w[PS_TOTAL] = 0u;
}

// Exclusive scan of one value per thread over the workgroup: (prefix, workgroup total).
// 16 threads scan 16 values each, one thread scans the 16 partial sums: three barriers
// (so WG must be 256 = 16 x 16; sort.py checks it).
fn ps_wg_scan(t: u32, v: u32) -> vec2<u32> {
    ps_sh[t] = v;
    workgroupBarrier();
    if (t < 16u) {
        var acc = 0u;
        for (var k = 0u; k < 16u; k++) {
            let i = t * 16u + k;
            let x = ps_sh[i];
            ps_sh[i] = acc;
            acc += x;
        }
        ps_part[t] = acc;
    }
    workgroupBarrier();
    if (t == 0u) {
        var acc = 0u;
        for (var k = 0u; k < 16u; k++) {
            let x = ps_part[k];
            ps_part[k] = acc;
            acc += x;
        }
        ps_part[16] = acc;
    }
    workgroupBarrier();
    return vec2<u32>(ps_sh[t] + ps_part[t >> 4u], ps_part[16]);
}

// Runs are read twice (sum, then scan-and-store) rather than kept in a private array: the run
// length is a pipeline constant, and in place each element is read before it is overwritten.

// v (elements g .. g + 3) with the elements at or past n zeroed.
fn ps_masked(v: vec4<u32>, g: u32, n: u32) -> vec4<u32> {
    return select(vec4<u32>(0u), v, vec4<u32>(g) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(n));
}

fn ps_hsum(v: vec4<u32>) -> u32 {
    return v.x + v.y + v.z + v.w;
}

fn ps_sum_src(lbase: u32, gbase: u32, n: u32) -> u32 {
    var s = 0u;
    for (var j = 0u; j < PS_PER / 4u; j++) {
        if (gbase + 4u * j < n) {
            s += ps_hsum(ps_masked(ps_src[(lbase >> 2u) + j], gbase + 4u * j, n));
        }
    }
    return s;
}

fn ps_sum_dst(lbase: u32, gbase: u32, n: u32) -> u32 {
    var s = 0u;
    for (var j = 0u; j < PS_PER / 4u; j++) {
        if (gbase + 4u * j < n) {
            s += ps_hsum(ps_masked(ps_dst[(lbase >> 2u) + j], gbase + 4u * j, n));
        }
    }
    return s;
}

// Writes the exclusive scan of v (offset acc) to ps_dst[i]; returns acc + sum(v).
fn ps_put(i: u32, g: u32, n: u32, v: vec4<u32>, acc: u32) -> u32 {
    let out = vec4<u32>(acc, acc + v.x, acc + v.x + v.y, acc + v.x + v.y + v.z);
    if (g + 4u <= n) {
        ps_dst[i] = out;
    } else {
        ps_dst[i] = select(ps_dst[i], out, vec4<u32>(g) + vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(n));
    }
    return out.w + v.w;
}

fn ps_store_from_src(lbase: u32, gbase: u32, n: u32, offset: u32) {
    var acc = offset;
    for (var j = 0u; j < PS_PER / 4u; j++) {
        let g = gbase + 4u * j;
        if (g < n) {
            let i = (lbase >> 2u) + j;
            acc = ps_put(i, g, n, ps_masked(ps_src[i], g, n), acc);
        }
    }
}

fn ps_store_from_dst(lbase: u32, gbase: u32, n: u32, offset: u32) {
    var acc = offset;
    for (var j = 0u; j < PS_PER / 4u; j++) {
        let g = gbase + 4u * j;
        if (g < n) {
            let i = (lbase >> 2u) + j;
            acc = ps_put(i, g, n, ps_masked(ps_dst[i], g, n), acc);
        }
    }
}

// Number of valid workgroups of this chunk's dispatch (the 2-D grid may have a few extra).
fn ps_groups(n: u32) -> u32 {
    let nb = (n + PS_BLOCK - 1u) / PS_BLOCK;
    if (nb <= ps_pass.block0) {
        return 0u;
    }
    return min(nb - ps_pass.block0, ps_pass.bpc);
}

@compute @workgroup_size(WG)
fn ps_reduce(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = ps_plan[ps_pass.level];
    if (wid >= ps_groups(n)) {
        return;
    }
    let lbase = wid * PS_BLOCK + t * PS_PER;
    let gbase = ps_pass.block0 * PS_BLOCK + lbase;
    let r = ps_wg_scan(t, ps_sum_src(lbase, gbase, n));
    if (t == 0u) {
        ps_sums[ps_pass.block0 + wid] = r.y;
    }
}

@compute @workgroup_size(WG)
fn ps_downsweep(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = ps_plan[ps_pass.level];
    if (wid >= ps_groups(n)) {
        return;
    }
    let lbase = wid * PS_BLOCK + t * PS_PER;
    let gbase = ps_pass.block0 * PS_BLOCK + lbase;
    let r = ps_wg_scan(t, ps_sum_src(lbase, gbase, n));
    ps_store_from_src(lbase, gbase, n, ps_offs[ps_pass.block0 + wid] + r.x);
}

@compute @workgroup_size(WG)
fn ps_downsweep_inplace(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                        @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = ps_plan[ps_pass.level];
    if (wid >= ps_groups(n)) {
        return;
    }
    let lbase = wid * PS_BLOCK + t * PS_PER;
    let gbase = ps_pass.block0 * PS_BLOCK + lbase;
    let r = ps_wg_scan(t, ps_sum_dst(lbase, gbase, n));
    ps_store_from_dst(lbase, gbase, n, ps_offs[ps_pass.block0 + wid] + r.x);
}

// The top level (at most one block) in a single workgroup; also records the grand total.
@compute @workgroup_size(WG)
fn ps_top(@builtin(local_invocation_index) t: u32) {
    let n = ps_plan_w[ps_pass.level];
    let r = ps_wg_scan(t, ps_sum_src(t * PS_PER, t * PS_PER, n));
    ps_store_from_src(t * PS_PER, t * PS_PER, n, r.x);
    if (t == 0u) {
        ps_plan_w[PS_TOTAL] = r.y;
    }
}

@compute @workgroup_size(WG)
fn ps_top_inplace(@builtin(local_invocation_index) t: u32) {
    let n = ps_plan_w[ps_pass.level];
    let r = ps_wg_scan(t, ps_sum_dst(t * PS_PER, t * PS_PER, n));
    ps_store_from_dst(t * PS_PER, t * PS_PER, n, r.x);
    if (t == 0u) {
        ps_plan_w[PS_TOTAL] = r.y;
    }
}
