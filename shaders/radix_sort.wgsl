// #import common

// Stable LSD radix sort of (u32 key, u32 value) pairs, 4 bits per pass (seuwgpu/gpu/sort.py).
//
// A block is WG (256) threads x RS_PER elements; each thread owns RS_PER contiguous elements. Per pass:
// `rs_upsweep` counts each thread's digits, scans them over the workgroup and stores the block's
// digit counts in hist[digit * blocks + block] and each thread's first position per digit inside
// the block in rs_offs; PrefixSum scans the digit-major hist, so hist[d * blocks + b] becomes the
// output position of block b's first element with digit d; `rs_scatter` walks each thread's run
// in order and writes every pair to hist + thread offset + its rank among equal digits so far.
// Small histograms skip the PrefixSum: `rs_scatter` with RS_FUSED computes its block's 16 positions from
// the unscanned hist (two dispatches a pass instead of three).
// Threads own contiguous runs, so equal keys keep their input order (stable), and no workgroup
// waits for another (no forward-progress assumption).
//
// Cost model (lavapipe; harmless on GPUs): lavapipe runs 8 invocations per SIMD instruction but
// performs each memory access with a non-uniform address lane by lane, and a workgroup barrier
// costs it ~5 us. So keys and values are read as vec4, per-thread digit counts live in registers
// (8-bit fields, four digits per u32: a run has at most RS_PER <= 252 of a digit) and are
// exchanged as vec4 of 16-bit fields (a block has at most 256 RS_PER < 65536 of a digit: no
// carry between fields), output positions are selected from registers, and the scatter has no
// barrier and no workgroup memory (but for RS_FUSED, which only GPUs compile: sort.py).
//
// Arrays larger than one storage binding: inputs are read chunk by chunk (one dispatch per chunk,
// bound at the chunk's offset), outputs are bound as two halves split at `rs_pass.split`; the
// pipeline constant RS_TWO_PARTS compiles the second half in only where it is needed.
// Workgroup memory is written before it is read (lavapipe does not zero it).

// Elements per thread, a multiple of 4 in [4, 252]. sort.py: 64 on CPU adapters (fewer
// workgroups, so fewer barriers), 16 on GPUs (enough workgroups to fill the device).
override RS_PER: u32 = 16u;
override RS_BLOCK: u32 = WG * RS_PER;
// Workgroups per dispatch row; larger grids are 2-D (overridable so that tests reach that path).
override RS_MAX_X: u32 = MAX_GROUPS_X;
// Outputs span two bindings (sort.py sets it only then: the branch costs lavapipe per element).
override RS_TWO_PARTS: bool = false;
// Plan buffer layout (u32 words; RS_HIST_COUNT, RS_ARGS and RS_OFFS from sort.py's RADIX_PLAN):
// [0] count, [1] blocks, [RS_HIST_COUNT] 16 * blocks (the scan's count), [RS_ARGS + 3c ..)
// indirect args of chunk c.

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

// Inputs are read as vec4; buffer sizes are multiples of 16 bytes.
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
@group(0) @binding(12) var<storage, read_write> rs_keys_out4: array<vec4<u32>>;
@group(0) @binding(13) var<storage, read_write> rs_vals_out4: array<vec4<u32>>;
// Per-thread first positions within the block (16-bit fields, see rs_widen), written by the
// upsweep: thread g of the whole array at [RS_OFFS + 2g] (digits 0..7) and [RS_OFFS + 2g + 1]
// (8..15). [0] is a header (count, blocks) that the plan kernel writes, so that the scatter finds
// them without a ninth storage binding.
@group(0) @binding(14) var<storage, read> rs_offs: array<vec4<u32>>;
@group(0) @binding(15) var<storage, read_write> rs_offs_w: array<vec4<u32>>;
// This dispatch's slot of the sorter's pass table (bound at an offset, with the arrays).
@group(0) @binding(16) var<uniform> rs_pass: RsPass;

// Upsweep scratch: per-thread counts, 16-bit fields: [half][thread] (half 0 = digits 0..7), and
// [half][16 thread groups] partial sums. 8.5 KiB.
var<workgroup> rs_cnt: array<vec4<u32>, 2u * WG>;
var<workgroup> rs_part: array<vec4<u32>, 32>;

@compute @workgroup_size(1)
fn rs_plan_main() {
    let n = min(rs_count[rs_pargs.word], rs_pargs.limit);
    let nb = (n + RS_BLOCK - 1u) / RS_BLOCK;
    rs_plan_w[0] = n;
    rs_plan_w[1] = nb;
    rs_plan_w[RS_HIST_COUNT] = nb * 16u;
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
    rs_offs_w[0] = vec4<u32>(n, nb, 0u, 0u);
}

// Number of valid workgroups of this chunk's dispatch (the 2-D grid may have a few extra).
fn rs_groups(nb: u32) -> u32 {
    if (nb <= rs_pass.block0) {
        return 0u;
    }
    return min(nb - rs_pass.block0, rs_pass.bpc);
}

const RS_SEL: vec4<u32> = vec4<u32>(0u, 1u, 2u, 3u);

fn rs_digit(key: u32) -> u32 {
    return (key >> rs_pass.shift) & rs_pass.mask;
}

// One-hot increment of digit d in four words of 8-bit counters (word d / 4, byte d % 4).
fn rs_inc8(d: u32) -> vec4<u32> {
    return select(vec4<u32>(0u), vec4<u32>(1u << ((d & 3u) << 3u)), vec4<u32>(d >> 2u) == RS_SEL);
}

// Component d % 4 of the d / 4-th of four vectors, by selects (registers, no memory access).
fn rs_pick(a: vec4<u32>, b: vec4<u32>, c: vec4<u32>, e: vec4<u32>, d: u32) -> u32 {
    let q = d >> 2u;
    let v = select(select(e, c, q == 2u), select(b, a, q == 0u), q < 2u);
    return v[d & 3u];
}

// Digit counts of the thread's run, 8-bit fields (digit d: word d / 4, byte d % 4).
fn rs_count_run(lbase: u32, gbase: u32, n: u32) -> vec4<u32> {
    var c = vec4<u32>(0u);
    for (var j = 0u; j < RS_PER / 4u; j++) {
        if (gbase + 4u * j < n) {
            let k4 = rs_keys_in[(lbase >> 2u) + j];
            for (var e = 0u; e < 4u; e++) {
                if (gbase + 4u * j + e < n) {
                    c += rs_inc8(rs_digit(k4[e]));
                }
            }
        }
    }
    return c;
}

// 8-bit fields of two counter words (digits 0..7 of a half) -> 16-bit fields, two digits per
// component: x = digits 0 | 2 << 16, y = 1 | 3 << 16, z = 4 | 6 << 16, w = 5 | 7 << 16.
fn rs_widen(a: u32, b: u32) -> vec4<u32> {
    let m = 0x00ff00ffu;
    return vec4<u32>(a & m, (a >> 8u) & m, b & m, (b >> 8u) & m);
}

// Upsweep: digit counts of the block into hist[digit * blocks + block] and each thread's first
// position per digit within the block into rs_offs (exclusive scan over the threads), so that
// the scatter needs neither workgroup memory nor barriers (each barrier costs lavapipe ~5 us).
@compute @workgroup_size(WG)
fn rs_upsweep(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = rs_plan[0];
    let nb = rs_plan[1];
    if (wid >= rs_groups(nb)) {
        return;
    }
    let block = rs_pass.block0 + wid;
    let lbase = wid * RS_BLOCK + t * RS_PER;
    let c = rs_count_run(lbase, block * RS_BLOCK + t * RS_PER, n);
    rs_cnt[t] = rs_widen(c.x, c.y);
    rs_cnt[WG + t] = rs_widen(c.z, c.w);
    workgroupBarrier();
    // 32 threads scan 16 threads' counts each (half t / 16, threads 16 (t % 16) .. + 15) ...
    if (t < 32u) {
        let b = (t >> 4u) * WG + (t & 15u) * 16u;
        var acc = vec4<u32>(0u);
        for (var k = 0u; k < 16u; k++) {
            let x = rs_cnt[b + k];
            rs_cnt[b + k] = acc;
            acc += x;
        }
        rs_part[t] = acc;
    }
    workgroupBarrier();
    // ... then two threads scan the 16 group sums of their half and store the block's counts.
    if (t < 2u) {
        var acc = vec4<u32>(0u);
        for (var g = 0u; g < 16u; g++) {
            let x = rs_part[t * 16u + g];
            rs_part[t * 16u + g] = acc;
            acc += x;
        }
        let d0 = 8u * t;
        let m = 0xffffu;
        rs_hist_w[d0 * nb + block] = acc.x & m;
        rs_hist_w[(d0 + 1u) * nb + block] = acc.y & m;
        rs_hist_w[(d0 + 2u) * nb + block] = acc.x >> 16u;
        rs_hist_w[(d0 + 3u) * nb + block] = acc.y >> 16u;
        rs_hist_w[(d0 + 4u) * nb + block] = acc.z & m;
        rs_hist_w[(d0 + 5u) * nb + block] = acc.w & m;
        rs_hist_w[(d0 + 6u) * nb + block] = acc.z >> 16u;
        rs_hist_w[(d0 + 7u) * nb + block] = acc.w >> 16u;
    }
    workgroupBarrier();
    let o = RS_OFFS + 2u * (block * WG + t);
    rs_offs_w[o] = rs_cnt[t] + rs_part[t >> 4u];
    rs_offs_w[o + 1u] = rs_cnt[WG + t] + rs_part[16u + (t >> 4u)];
}

// Fused-scan scratch: thread t's sums of digit t / 16 over the blocks b = t (mod 16), all of them
// and those before this workgroup's block; then per digit (16 threads).
var<workgroup> rs_tot: array<u32, WG>;
var<workgroup> rs_pre: array<u32, WG>;
var<workgroup> rs_dtot: array<u32, 16>;
var<workgroup> rs_dpre: array<u32, 16>;

// Exclusive scan of the four components, plus `carry`.
fn rs_excl4(v: vec4<u32>, carry: u32) -> vec4<u32> {
    return vec4<u32>(carry, carry + v.x, carry + v.x + v.y, carry + v.x + v.y + v.z);
}

// Digits 4q .. 4q + 3 of hist column `block` (after the PrefixSum: that block's bases).
fn rs_hist4(q: u32, nb: u32, block: u32) -> vec4<u32> {
    let r = 4u * q * nb + block;
    return vec4<u32>(rs_hist[r], rs_hist[r + nb], rs_hist[r + 2u * nb], rs_hist[r + 3u * nb]);
}

// RS_FUSED: the hist is unscanned, and each workgroup computes its block's 16 bases itself (digit
// d: the counts of all digits below d in every block, plus digit d's counts in the blocks before
// this one), so a pass needs no PrefixSum dispatch between upsweep and scatter; sort.py sets it
// on GPUs while a histogram has at most FUSED_MAX_BLOCKS blocks (a thread then reads at most 16
// of its words). The bases, and so the output, are those read from the scanned hist.
override RS_FUSED: bool = false;

// Scatter: each thread walks its run in order and writes every pair to its digit's block base +
// the thread's first position in the block (upsweep) + its rank among equal digits so far in the
// run (8-bit counters in registers). No workgroup memory and no barrier unless RS_FUSED.
@compute @workgroup_size(WG)
fn rs_scatter(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let hdr = rs_offs[0];
    let n = hdr.x;
    let nb = hdr.y;
    if (wid >= rs_groups(nb)) {
        return;
    }
    let block = rs_pass.block0 + wid;
    // Base of digit d at [d / 4][d % 4].
    var b0: vec4<u32>;
    var b1: vec4<u32>;
    var b2: vec4<u32>;
    var b3: vec4<u32>;
    if (RS_FUSED) {
        let row = (t >> 4u) * nb;
        var tot = 0u;
        var pre = 0u;
        for (var b = t & 15u; b < nb; b += 16u) {
            let c = rs_hist[row + b];
            tot += c;
            pre += select(0u, c, b < block);
        }
        rs_tot[t] = tot;
        rs_pre[t] = pre;
        workgroupBarrier();
        if (t < 16u) {
            var dt = 0u;
            var dp = 0u;
            for (var s = 0u; s < 16u; s++) {
                dt += rs_tot[16u * t + s];
                dp += rs_pre[16u * t + s];
            }
            rs_dtot[t] = dt;
            rs_dpre[t] = dp;
        }
        workgroupBarrier();
        let t0 = vec4<u32>(rs_dtot[0], rs_dtot[1], rs_dtot[2], rs_dtot[3]);
        let t1 = vec4<u32>(rs_dtot[4], rs_dtot[5], rs_dtot[6], rs_dtot[7]);
        let t2 = vec4<u32>(rs_dtot[8], rs_dtot[9], rs_dtot[10], rs_dtot[11]);
        let t3 = vec4<u32>(rs_dtot[12], rs_dtot[13], rs_dtot[14], rs_dtot[15]);
        let c1 = t0.x + t0.y + t0.z + t0.w;
        let c2 = c1 + t1.x + t1.y + t1.z + t1.w;
        let c3 = c2 + t2.x + t2.y + t2.z + t2.w;
        b0 = rs_excl4(t0, 0u) + vec4<u32>(rs_dpre[0], rs_dpre[1], rs_dpre[2], rs_dpre[3]);
        b1 = rs_excl4(t1, c1) + vec4<u32>(rs_dpre[4], rs_dpre[5], rs_dpre[6], rs_dpre[7]);
        b2 = rs_excl4(t2, c2) + vec4<u32>(rs_dpre[8], rs_dpre[9], rs_dpre[10], rs_dpre[11]);
        b3 = rs_excl4(t3, c3) + vec4<u32>(rs_dpre[12], rs_dpre[13], rs_dpre[14], rs_dpre[15]);
    } else {
        b0 = rs_hist4(0u, nb, block);
        b1 = rs_hist4(1u, nb, block);
        b2 = rs_hist4(2u, nb, block);
        b3 = rs_hist4(3u, nb, block);
    }
    let lbase = wid * RS_BLOCK + t * RS_PER;
    let gbase = block * RS_BLOCK + t * RS_PER;
    let o = RS_OFFS + 2u * (block * WG + t);
    let lo = rs_offs[o];
    let hi = rs_offs[o + 1u];
    // Output position of this thread's first element of each digit: f0..f3 (digit d at [d/4][d%4]);
    // lo.x = digits 0 | 2 << 16, lo.y = 1 | 3 << 16, lo.z = 4 | 6 << 16, lo.w = 5 | 7 << 16.
    let m = 0xffffu;
    let f0 = b0 + vec4<u32>(lo.x & m, lo.y & m, lo.x >> 16u, lo.y >> 16u);
    let f1 = b1 + vec4<u32>(lo.z & m, lo.w & m, lo.z >> 16u, lo.w >> 16u);
    let f2 = b2 + vec4<u32>(hi.x & m, hi.y & m, hi.x >> 16u, hi.y >> 16u);
    let f3 = b3 + vec4<u32>(hi.z & m, hi.w & m, hi.z >> 16u, hi.w >> 16u);
    var seen = vec4<u32>(0u);
    for (var j = 0u; j < RS_PER / 4u; j++) {
        if (gbase + 4u * j < n) {
            let k4 = rs_keys_in[(lbase >> 2u) + j];
            let v4 = rs_vals_in[(lbase >> 2u) + j];
            for (var e = 0u; e < 4u; e++) {
                if (gbase + 4u * j + e < n) {
                    let d = rs_digit(k4[e]);
                    let dst = rs_pick(f0, f1, f2, f3, d) + ((seen[d >> 2u] >> ((d & 3u) << 3u)) & 0xffu);
                    seen += rs_inc8(d);
                    if (RS_TWO_PARTS && dst >= rs_pass.split) {
                        rs_keys_hi[dst - rs_pass.split] = k4[e];
                        rs_vals_hi[dst - rs_pass.split] = v4[e];
                    } else {
                        rs_keys_lo[dst] = k4[e];
                        rs_vals_lo[dst] = v4[e];
                    }
                }
            }
        }
    }
}

// Copies count pairs from the inputs to rs_*_out4 (both bound at the chunk's offset), vec4 at a
// time (a partial last vec4 is copied whole: the destination is internal). An odd number of
// passes starts from the internal buffers so that the result ends in the caller's. Each thread
// copies short contiguous runs (measured faster on lavapipe than strided or long runs).
@compute @workgroup_size(WG)
fn rs_copy(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) t: u32) {
    let wid = linear_wg(wg, nwg);
    let n = rs_plan[0];
    if (wid >= rs_groups(rs_plan[1])) {
        return;
    }
    // Sub-blocks of 1024 vec4, four consecutive vec4 per thread.
    let nv = RS_BLOCK / 4u;
    let wbase = wid * nv;
    let gbase = rs_pass.block0 * nv + wbase;
    for (var s = 0u; s < (nv + 1023u) / 1024u; s++) {
        for (var k = 0u; k < 4u; k++) {
            let i = s * 1024u + t * 4u + k;
            if (i < nv && 4u * (gbase + i) < n) {
                rs_keys_out4[wbase + i] = rs_keys_in[wbase + i];
                rs_vals_out4[wbase + i] = rs_vals_in[wbase + i];
            }
        }
    }
}
