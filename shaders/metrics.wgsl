// #import ssim

// Per-injection image-difference reductions (seuwgpu/metrics/image.py drives these kernels).
//
// Images are float32 RGBA, 4 floats per pixel (rgb + final transmittance; the 4th channel is
// ignored). clean: [K, H, W] vec4. Faulted variants, two storage modes (params.sparse):
//   dense  (0): fimg = faulted [B, K, H, W] vec4, row-major;
//   sparse (1): fimg = slabs [S, TILE_PIXELS] vec4 (one tile per slab, pixel (tx, ty) at ty*TILE+tx),
//               tile_map i32 [B, K, TY*TX]: slab of that tile of variant b / view k, or -1 =
//               "identical to clean".
// Work list: one entry per (b, k, tile) to evaluate. Dense: every tile, implicit (entry e is
// bk = e / n_tiles, tile = e % n_tiles). Sparse: worklist u32 [E] holds tile indices
// (ty*TX + tx) grouped by bk = b*K + k in increasing bk order, with CSR offsets u32 [B*K + 1]
// (E = offsets[B*K]). Tiles not in the list are taken as identical to clean.
//
// Metric definitions (raw = the float32 render as stored; display = clipped to [0,1], NaN -> 0,
// +Inf -> 1, -Inf -> 0, i.e. what an 8-bit display shows):
//   changed   pixels with |f - c| > 1/255 in any of r,g,b (raw), or any non-finite faulted
//             channel, or a non-finite raw difference; a pixel whose r,g,b bits equal the
//             clean pixel's counts for none of changed, peak, nonfinite (a clean render's own
//             NaN pixels are not the upset's);
//   peak      max over pixels and channels of |f - c| (raw), +Inf if any of those is non-finite;
//   nonfinite pixels with any non-finite faulted r,g,b channel (exponent-bit test);
//   sse       sum over pixels x 3 channels of (display(f) - display(c))^2;
//   SSIM      skimage.metrics.structural_similarity(display(c), display(f), channel_axis=-1,
//             data_range=1) with its defaults (7x7 uniform window, sample covariance, K1 = 0.01,
//             K2 = 0.03, map cropped by 3 px): per interior window centre the mean over the 3
//             channels. The kernel accumulates the SSIM *deficit* 1 - SSIM (small numbers, so the
//             f32 sums stay accurate) and the count of evaluated interior centres; the host turns
//             that into ssim_sum = count - deficit.
//
// SSIM's windows: ssim.wgsl.
//
// Reductions are portable: one M_THREADS-thread workgroup per work-list entry (tile) reduces its
// pixels in workgroup memory in a fixed order and writes one partial record; a second kernel, one
// thread per (b, k), adds its entries' partials sequentially in entry order. Inserting entries
// whose partials are zero therefore leaves every sum bit-identical, which is why sparse mode
// (with a work list covering the changed tiles dilated by one tile) equals dense mode exactly.
// No float atomics.
//
// Records (partials [E] and results [B*K]): MetricsRecord; the results buffer starts with a
// MetricsStatus (entries requested (sparse: offsets[B*K]), entries evaluated (min with
// capacity), sparse flag). The host reads both through the same structs (gpu/kernel.py Struct).
// Workgroup memory: 15.5 KB at TILE = 16 (WebGPU's default limit is 16 KiB), all written before
// it is read. Besides its partial record, each entry writes its changed-pixel mask (m_masks).

struct MetricsParams {
    width: u32,
    height: u32,
    n_views: u32,
    n_bk: u32,          // B * K of this call
    tiles_x: u32,
    n_tiles: u32,
    capacity: u32,      // partial records that fit in the partials buffer
    sparse: u32,        // 0 dense, 1 sparse
};

@group(0) @binding(0) var<uniform> mp: MetricsParams;
@group(0) @binding(1) var<storage, read> m_clean: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> m_fimg: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> m_tile_map: array<i32>;
@group(0) @binding(4) var<storage, read> m_worklist: array<u32>;
@group(0) @binding(5) var<storage, read> m_offsets: array<u32>;
struct MetricsRecord {
    changed: u32,
    peak: f32,
    sse: f32,
    nonfinite: u32,
    deficit: f32,       // SSIM deficit
    count: u32,         // SSIM window centres
};

struct MetricsStatus {
    requested: u32,
    evaluated: u32,
    sparse: u32,
    _pad: u32,
};

struct MetricsResults {
    status: MetricsStatus,
    records: array<MetricsRecord>,
};

@group(0) @binding(6) var<storage, read_write> m_partials: array<MetricsRecord>;
@group(0) @binding(7) var<storage, read_write> m_results: MetricsResults;
@group(0) @binding(8) var<storage, read_write> m_indirect: array<u32>;
// changed-pixel mask of each evaluated entry: M_MASK_WORDS words, bit p of the tile's pixel
// p = ty * TILE + tx (word p / 32, bit p % 32): the sort-first contamination measure's input
@group(0) @binding(9) var<storage, read_write> m_masks: array<u32>;

const M_THREADS: u32 = TILE_PIXELS / 4u;  // 4 vertically adjacent pixels per thread
const M_SPAN: u32 = TILE + 6u;            // a tile and its 3-px SSIM halo on each side
const M_PLANE: u32 = M_SPAN * M_SPAN;
const M_THR: f32 = 1.0 / 255.0;
const M_MASK_WORDS: u32 = TILE_PIXELS / 32u;

// Display-referred rgb of the tile plus its 3-px halo: clean at [i], faulted at [M_PLANE + i]
// (i = hy * 22 + hx). Reused for the reduction once SSIM is done.
var<workgroup> m_blk: array<vec4<f32>, 2u * M_PLANE>;
// block cells (hx, hy) whose display rgb differ: min hx, max hx, min hy, max hy (empty: min > max)
var<workgroup> m_box: array<atomic<u32>, 4>;
var<workgroup> m_cmask: array<atomic<u32>, M_MASK_WORDS>;

fn m_inf() -> f32 {
    return bitcast<f32>(0x7f800000u);
}

// Display-referred value by bit tests only: NaN -> 0, negatives (and -0, -Inf) -> 0,
// >= 1 (and +Inf) -> 1.
fn m_display(x: f32) -> f32 {
    let b = bitcast<u32>(x);
    if ((b & 0x7fffffffu) > 0x7f800000u) {
        return 0.0;
    }
    if ((b & 0x80000000u) != 0u) {
        return 0.0;
    }
    if (b >= 0x3f800000u) {
        return 1.0;
    }
    return x;
}

fn m_entries() -> u32 {
    if (mp.sparse == 0u) {
        return mp.n_bk * mp.n_tiles;
    }
    return m_offsets[mp.n_bk];
}

fn m_clean_px(k: u32, x: u32, y: u32) -> vec4<f32> {
    return m_clean[(k * mp.height + y) * mp.width + x];
}

fn m_faulted_px(bk: u32, k: u32, x: u32, y: u32) -> vec4<f32> {
    if (mp.sparse == 0u) {
        return m_fimg[(bk * mp.height + y) * mp.width + x];
    }
    let t = (y / TILE) * mp.tiles_x + (x / TILE);
    let s = m_tile_map[bk * mp.n_tiles + t];
    if (s < 0) {
        return m_clean_px(k, x, y);
    }
    return m_fimg[u32(s) * TILE_PIXELS + (y % TILE) * TILE + (x % TILE)];
}

// bk of entry e in sparse mode: the largest bk with offsets[bk] <= e.
fn m_entry_bk(e: u32) -> u32 {
    var lo = 0u;
    var hi = mp.n_bk;       // offsets[lo] <= e < offsets[hi] (offsets[n_bk] = E > e)
    loop {
        if (hi - lo <= 1u) {
            break;
        }
        let mid = (lo + hi) >> 1u;
        if (m_offsets[mid] <= e) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}

fn m_disp3(v: vec4<f32>) -> vec3<f32> {
    return vec3<f32>(m_display(v.x), m_display(v.y), m_display(v.z));
}

// One M_THREADS-thread workgroup per work-list entry (a tile of one (variant, view)); each thread
// owns 4 pixels. Barriers are few on purpose: lavapipe runs barrier-separated phases as
// coroutines, and each barrier costs a switch per SIMD group.
@compute @workgroup_size(M_THREADS)
fn tile_partials(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) tid: u32) {
    let e = linear_wg(wg, nwg);
    let n_eval = min(m_entries(), mp.capacity);
    if (e >= n_eval) {
        return;     // uniform per workgroup
    }
    var bk = 0u;
    var tile = 0u;
    if (mp.sparse == 0u) {
        bk = e / mp.n_tiles;
        tile = e % mp.n_tiles;
    } else {
        bk = m_entry_bk(e);
        tile = m_worklist[e];
    }
    let valid_tile = tile < mp.n_tiles;
    let k = bk % mp.n_views;
    let W = mp.width;
    let H = mp.height;
    let ox = (tile % mp.tiles_x) * TILE;
    let oy = (tile / mp.tiles_x) * TILE;

    if (tid == 0u) {
        atomicStore(&m_box[0], 0xffffffffu);
        atomicStore(&m_box[1], 0u);
        atomicStore(&m_box[2], 0xffffffffu);
        atomicStore(&m_box[3], 0u);
    }
    if (tid < M_MASK_WORDS) {
        atomicStore(&m_cmask[tid], 0u);
    }
    workgroupBarrier();

    // ---- load the 22x22 block (every cell of m_blk is written: no stale workgroup memory);
    //      raw metrics for the cells that are pixels of this tile ----
    var changed = 0.0;
    var nonfin = 0.0;
    var peak = 0.0;
    var sse = 0.0;
    var dbox = vec4<u32>(0xffffffffu, 0u, 0xffffffffu, 0u);  // this thread's differing cells
    for (var i = tid; i < M_PLANE; i += M_THREADS) {
        let hx = i % M_SPAN;
        let hy = i / M_SPAN;
        let gx = i32(ox + hx) - 3;
        let gy = i32(oy + hy) - 3;
        var cd = vec3<f32>(0.0);
        var fd = vec3<f32>(0.0);
        if (valid_tile && gx >= 0 && gy >= 0 && u32(gx) < W && u32(gy) < H) {
            let c = m_clean_px(k, u32(gx), u32(gy));
            let f = m_faulted_px(bk, k, u32(gx), u32(gy));
            cd = m_disp3(c);
            fd = m_disp3(f);
            // a pixel bit-identical to the clean one is unchanged (a clean model's own NaN
            // pixels are not charged to the upset; tiles off the work list are taken the same)
            let same = all(bitcast<vec3<u32>>(f.xyz) == bitcast<vec3<u32>>(c.xyz));
            if (!same && hx >= 3u && hx < TILE + 3u && hy >= 3u && hy < TILE + 3u) {
                var bad = false;
                var over = false;
                var pk = 0.0;
                var nf = false;
                for (var ch = 0u; ch < 3u; ch++) {
                    if (!is_finite_f32(f[ch])) {
                        nf = true;
                    }
                    let d = f[ch] - c[ch];
                    if (!is_finite_f32(d)) {
                        bad = true;
                    } else {
                        let a = abs(d);
                        pk = max(pk, a);
                        if (a > M_THR) {
                            over = true;
                        }
                    }
                }
                if (nf || bad) {
                    pk = m_inf();
                    over = true;
                }
                if (nf) {
                    nonfin += 1.0;
                }
                if (over) {
                    changed += 1.0;
                    let p = (hy - 3u) * TILE + (hx - 3u);
                    atomicOr(&m_cmask[p / 32u], 1u << (p % 32u));
                }
                peak = max(peak, pk);
                let dd = fd - cd;
                sse += dot(dd, dd);
            }
        }
        m_blk[i] = vec4<f32>(cd, 0.0);
        m_blk[M_PLANE + i] = vec4<f32>(fd, 0.0);
        if (any(bitcast<vec3<u32>>(cd) != bitcast<vec3<u32>>(fd))) {
            dbox = vec4<u32>(min(dbox.x, hx), max(dbox.y, hx), min(dbox.z, hy), max(dbox.w, hy));
        }
    }
    if (dbox.x <= dbox.y) {  // some cell of this thread differs
        atomicMin(&m_box[0], dbox.x);
        atomicMax(&m_box[1], dbox.y);
        atomicMin(&m_box[2], dbox.z);
        atomicMax(&m_box[3], dbox.w);
    }
    workgroupBarrier();

    // ---- SSIM at interior window centres, skipped where every window is identical in clean and
    //      faulted (its deficit would be exactly 0: e1 = e2 = 0, see above): a thread whose 7 x 10
    //      cells (its 4 windows) miss the box of the differing cells, every thread when none differs ----
    let diff_box = vec4<u32>(atomicLoad(&m_box[0]), atomicLoad(&m_box[1]), atomicLoad(&m_box[2]), atomicLoad(&m_box[3]));
    if (tid < M_MASK_WORDS) {
        m_masks[e * M_MASK_WORDS + tid] = atomicLoad(&m_cmask[tid]);
    }
    var count = 0.0;
    var deficit = 0.0;
    let lx = tid % TILE;
    let ly0 = (tid / TILE) * 4u;            // this thread's centres: (lx, ly0 .. ly0 + 3)
    let x = ox + lx;
    let y = vec4<u32>(oy + ly0) + vec4<u32>(0u, 1u, 2u, 3u);
    let col_ok = valid_tile && x >= 3u && x + 3u < W;
    let interior = vec4<bool>(col_ok) & (y >= vec4<u32>(3u)) & (y + vec4<u32>(3u) < vec4<u32>(H));
    if (any(interior)) {
        let flag = select(vec4<f32>(0.0), vec4<f32>(1.0), interior);
        count = flag.x + flag.y + flag.z + flag.w;
        // cells lx .. lx + 6, ly0 .. ly0 + 9 (block coordinates) meet the box (never an empty one:
        // its min is 0xffffffff)
        let meets = diff_box.x <= lx + 6u && diff_box.y >= lx && diff_box.z <= ly0 + 9u && diff_box.w >= ly0;
        if (meets) {
            let q = m_ssim4(lx, ly0) * flag;
            deficit = q.x + q.y + q.z + q.w;
        }
    }

    // ---- workgroup reduction: thread 0 adds the M_THREADS per-thread records in order ----
    workgroupBarrier();
    m_blk[tid] = vec4<f32>(changed, peak, sse, nonfin);
    m_blk[M_THREADS + tid] = vec4<f32>(deficit, count, 0.0, 0.0);
    workgroupBarrier();
    if (tid == 0u) {
        var r_sum = vec4<f32>(0.0);     // changed, -, sse, nonfinite
        var r_peak = 0.0;
        var r_ssim = vec2<f32>(0.0);    // deficit, count
        for (var t = 0u; t < M_THREADS; t++) {
            let v = m_blk[t];
            r_sum += vec4<f32>(v.x, 0.0, v.z, v.w);
            r_peak = max(r_peak, v.y);
            r_ssim += m_blk[M_THREADS + t].xy;
        }
        let r_changed = r_sum.x;
        let r_sse = r_sum.z;
        let r_nonfin = r_sum.w;
        let r_deficit = r_ssim.x;
        let r_count = r_ssim.y;
        m_partials[e] = MetricsRecord(u32(r_changed), r_peak, r_sse, u32(r_nonfin), r_deficit, u32(r_count));
    }
}

// One thread per (b, k): sequential sum of its entries' partials, in entry order.
@compute @workgroup_size(WG)
fn reduce_entries(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let bk = linear_id(gid, nwg);
    if (bk >= mp.n_bk) {
        return;
    }
    let n_eval = min(m_entries(), mp.capacity);
    var lo = bk * mp.n_tiles;
    var hi = lo + mp.n_tiles;
    if (mp.sparse != 0u) {
        lo = m_offsets[bk];
        hi = m_offsets[bk + 1u];
    }
    hi = min(hi, n_eval);
    var changed = 0u;
    var peak = 0.0;
    var sse = 0.0;
    var nonfin = 0u;
    var deficit = 0.0;
    var count = 0u;
    for (var e = lo; e < hi; e++) {
        let r = m_partials[e];
        changed += r.changed;
        peak = max(peak, r.peak);
        sse += r.sse;
        nonfin += r.nonfinite;
        deficit += r.deficit;
        count += r.count;
    }
    m_results.records[bk] = MetricsRecord(changed, peak, sse, nonfin, deficit, count);
    if (bk == 0u) {
        m_results.status = MetricsStatus(m_entries(), n_eval, mp.sparse, 0u);
    }
}

// Sparse mode: indirect dispatch size for tile_partials from the work list length.
@compute @workgroup_size(1)
fn sparse_dispatch() {
    let n = min(m_entries(), mp.capacity);
    var gx = min(n, MAX_GROUPS_X);
    var gy = (n + MAX_GROUPS_X - 1u) / MAX_GROUPS_X;
    if (n == 0u) {
        gx = 0u;
        gy = 1u;
    }
    m_indirect[0] = gx;
    m_indirect[1] = gy;
    m_indirect[2] = 1u;
}
