// Front-to-back compositing (render/composite.py): one workgroup per TILE x TILE tile, each
// invocation compositing a column of QUAD (4) vertically adjacent pixels as vec4 lanes (the
// splat's x offset, staged record and loop overhead are shared by the four; on CPU Vulkan, 4x fewer
// invocations also means 4x fewer barrier context switches). Intersections are staged through
// workgroup memory in batches of BATCH records. Rules (skips, NaN-propagating min, early stop)
// are in docs/renderer.md. Output pixel = (C + T * background, T).
//
// Exactness: every pixel runs the per-pixel rule with the same operations in the same order as a
// one-pixel-per-invocation loop would (the lanes are independent; skips and stops are masks).
// Two shortcuts skip work that cannot change a pixel:
// - a staged record carries `cut`, a sigma beyond which alpha < 1/255 for certain (its opacity o:
//   ln(255 o) + 0.01, a margin far above exp's error; -Inf when o < 0.001, where alpha < 1/255
//   for every sigma >= 0; +Inf when o is NaN or huge, never cut): lanes past it skip without exp;
// - an invocation whose four pixels have stopped leaves the batch loop; the workgroup leaves the
//   tile when all its pixels have stopped.
//
// Two entry points share the blending code, so their arithmetic is identical bit for bit:
// - main: a tile of a full frame;
// - variants: a tile of a single-upset variant, re-composited from the clean frame's tile list
//   with the corrupted primitive removed and its re-projected record merged in at its depth
//   (render/incremental.py; equal to a full re-render bit for bit).

const QUAD: u32 = 4u;                       // pixels per invocation (one column)
const ROWS: u32 = TILE / QUAD;              // invocation rows per tile
const LANES: u32 = TILE * ROWS;             // invocations per workgroup
const BATCH: u32 = TILE_PIXELS;             // records staged per batch
const PER_LANE: u32 = BATCH / LANES;        // records each invocation stages per batch

var<workgroup> s_xy: array<vec4<f32>, BATCH>;     // mean x, mean y, cut, 0
var<workgroup> s_conic: array<vec4<f32>, BATCH>;  // conic, opacity
var<workgroup> s_rgb: array<vec4<f32>, BATCH>;
var<workgroup> s_done: atomic<u32>;
var<workgroup> s_all_done: u32;

// Four pixels (x, y0 + i), i = 0..3, in vec4 lanes.
struct Quad {
    x: f32,
    y: vec4<f32>,
    r: vec4<f32>,
    g: vec4<f32>,
    b: vec4<f32>,
    T: vec4<f32>,
    done: vec4<bool>,
};

fn inf_f32() -> f32 {
    return bitcast<f32>(0x7f800000u);
}

fn nan4(v: vec4<f32>) -> vec4<bool> {
    return (bitcast<vec4<u32>>(v) & vec4<u32>(0x7fffffffu)) > vec4<u32>(0x7f800000u);
}

// Sigma beyond which a record of opacity o cannot reach alpha >= 1/255 (see the header).
fn cut_of(o: f32) -> f32 {
    if ((bitcast<u32>(o) & 0x7fffffffu) > 0x7149f2cau) {
        return inf_f32();  // NaN, infinite or |o| > 1e30: never cut
    }
    if (o < 0.001) {
        return -inf_f32();
    }
    return log(255.0 * o) + 0.01;
}

// Stage one record (screen mean, conic + opacity, rgb) at slot i.
fn stage(i: u32, xy: vec2<f32>, co: vec4<f32>, rgb: vec4<f32>) {
    s_xy[i] = vec4<f32>(xy, cut_of(co.w), 0.0);
    s_conic[i] = co;
    s_rgb[i] = rgb;
}

// The quad of pixel centres (x, y0 + i) + 0.5 in full-frame coordinates; `done` lanes are not drawn.
fn make_quad(x: u32, y0: u32, done: vec4<bool>) -> Quad {
    let yf = f32(y0) + 0.5;
    return Quad(f32(x) + 0.5, vec4<f32>(yf, yf + 1.0, yf + 2.0, yf + 3.0), vec4<f32>(0.0), vec4<f32>(0.0),
                vec4<f32>(0.0), vec4<f32>(1.0), done);
}

// Lanes of a quad inside the width x height viewport (tile-local x, y0).
fn inside_quad(x: u32, y0: u32, width: u32, height: u32) -> vec4<bool> {
    let ys = vec4<u32>(y0) + vec4<u32>(0u, 1u, 2u, 3u);
    return vec4<bool>(x < width) & (ys < vec4<u32>(height));
}

// Count an invocation whose lanes are all finished before the first batch (after s_done's reset
// and a barrier).
fn count_if_done(q: ptr<function, Quad>) {
    if (all((*q).done)) {
        atomicAdd(&s_done, 1u);
    }
}

// sigma of a record at the quad's pixels, in the per-pixel rule's operation order.
fn sigma_of(xy: vec2<f32>, co: vec4<f32>, q: ptr<function, Quad>) -> vec4<f32> {
    let dx = xy.x - (*q).x;
    let dy = vec4<f32>(xy.y) - (*q).y;
    return 0.5 * (vec4<f32>(co.x * dx * dx) + co.z * dy * dy) + (co.y * dx) * dy;
}

// alpha (NaN propagating) of a record at sigma, and whether each lane takes part in the blend.
struct Alpha {
    alpha: vec4<f32>,
    hit: vec4<bool>,
};

fn alpha_of(sigma: vec4<f32>, o: f32) -> Alpha {
    let s_nan = nan4(sigma);
    let x = -sigma;
    var e = exp(x);
    e = select(e, vec4<f32>(0.0), x < vec4<f32>(-103.97208));
    e = select(e, vec4<f32>(inf_f32()), x > vec4<f32>(88.72283));
    e = select(e, x, s_nan);
    let a = o * e;
    let a_nan = nan4(a);
    let alpha = select(min(vec4<f32>(0.99), a), a, a_nan);
    let skip = (!s_nan & (sigma < vec4<f32>(0.0))) | (!nan4(alpha) & (alpha < vec4<f32>(1.0 / 255.0)));
    return Alpha(alpha, !skip);
}

// Blend the m staged records into the quad.
fn blend_batch(q: ptr<function, Quad>, m: u32) {
    if (all((*q).done)) {
        return;
    }
    var T = (*q).T;
    var r = (*q).r;
    var g = (*q).g;
    var b = (*q).b;
    var done = (*q).done;
    for (var k = 0u; k < m; k = k + 1u) {
        let st = s_xy[k];
        let co = s_conic[k];
        let sigma = sigma_of(st.xy, co, q);
        // lanes that may take part: not stopped, and sigma neither negative nor past the cut
        let gone = !nan4(sigma) & ((sigma < vec4<f32>(0.0)) | (sigma > vec4<f32>(st.z)));
        if (!any(!done & !gone)) {
            continue;
        }
        let al = alpha_of(sigma, co.w);
        let alpha = al.alpha;
        let hit = al.hit & !done;
        let next_t = T * (1.0 - alpha);
        let stop = hit & !nan4(next_t) & (next_t <= vec4<f32>(1e-4));
        let upd = hit & !stop;
        let rgb = s_rgb[k];
        let w = alpha * T;
        r = select(r, r + rgb.x * w, upd);
        g = select(g, g + rgb.y * w, upd);
        b = select(b, b + rgb.z * w, upd);
        T = select(T, next_t, upd);
        done = done | stop;
        if (all(done)) {
            atomicAdd(&s_done, 1u);
            break;
        }
    }
    (*q).T = T;
    (*q).r = r;
    (*q).g = g;
    (*q).b = b;
    (*q).done = done;
}

// After a batch: true (uniformly) when every invocation of the tile is finished.
fn all_done(li: u32) -> bool {
    workgroupBarrier();
    if (li == 0u) {
        s_all_done = atomicLoad(&s_done);
    }
    return workgroupUniformLoad(&s_all_done) == LANES;
}

// Pixel i of the quad as the output (C + T * background, T).
fn out_pixel(q: Quad, i: u32, bg: vec3<f32>) -> vec4<f32> {
    let T = q.T[i];
    return vec4<f32>(vec3<f32>(q.r[i], q.g[i], q.b[i]) + T * bg, T);
}

// ---- full frame -----------------------------------------------------------------------------
@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> isect_prims: array<u32>;
@group(0) @binding(3) var<storage, read> proj_xy: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> proj_conic: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> proj_rgb: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> image: array<vec4<f32>>;

@compute @workgroup_size(TILE, ROWS)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let tile = wg.y * bin.tiles_x + wg.x;
    let x = wg.x * TILE + lid.x;
    let y0 = wg.y * TILE + lid.y * QUAD;
    let inside = inside_quad(x, y0, bin.width, bin.height);
    // pixel centres in full-frame coordinates (a sort-first region starts at `origin`)
    var q = make_quad(x + (bin.origin & 0xffffu), y0 + (bin.origin >> 16u), !inside);
    if (li == 0u) {
        atomicStore(&s_done, 0u);
    }
    workgroupBarrier();
    count_if_done(&q);
    let range = ranges[tile];
    let n = range.y - range.x;
    let batches = (n + BATCH - 1u) / BATCH;
    for (var bt = 0u; bt < batches; bt = bt + 1u) {
        for (var s = 0u; s < PER_LANE; s = s + 1u) {
            let i = s * LANES + li;
            let idx = range.x + bt * BATCH + i;
            if (idx < range.y) {
                let g = isect_prims[idx];
                stage(i, proj_xy[g], proj_conic[g], proj_rgb[g]);
            }
        }
        workgroupBarrier();
        blend_batch(&q, min(BATCH, n - bt * BATCH));
        if (all_done(li)) {
            break;
        }
    }
    let bg = bin.background.xyz;
    for (var i = 0u; i < QUAD; i = i + 1u) {
        if (inside[i]) {
            image[(bin.stats_index * bin.height + y0 + i) * bin.width + x] = out_pixel(q, i, bg);
        }
    }
}

// ---- single-upset variants ------------------------------------------------------------------
struct Recomp {
    width: u32,
    height: u32,
    tiles_x: u32,
    n_tiles: u32,
    n_prims: u32,       // primitives of the model (stride of the per-view clean arrays)
    n_variants: u32,    // stride of the per-view variant arrays
    capacity: u32,      // stride of the per-view clean tile lists
    n_entries: u32,
    background: vec4<f32>,
};

@group(0) @binding(10) var<uniform> rc: Recomp;
// One tile of one variant to re-composite.
struct VariantEntry {
    variant: u32,       // index of the variant's records (per view, n_variants apart)
    view: u32,
    tile: u32,
    prim: u32,          // the primitive the variant changes
};

@group(0) @binding(11) var<storage, read> entries: array<VariantEntry>;
@group(0) @binding(12) var<storage, read> kv_ranges: array<vec2<u32>>;
@group(0) @binding(13) var<storage, read> kv_isect: array<u32>;
@group(0) @binding(14) var<storage, read> kv_xy: array<vec2<f32>>;
@group(0) @binding(15) var<storage, read> kv_conic: array<vec4<f32>>;
@group(0) @binding(16) var<storage, read> kv_rgb: array<vec4<f32>>;     // w = depth
@group(0) @binding(17) var<storage, read> var_xy: array<vec2<f32>>;
@group(0) @binding(18) var<storage, read> var_conic: array<vec4<f32>>;
@group(0) @binding(19) var<storage, read> var_rgb: array<vec4<f32>>;
@group(0) @binding(20) var<storage, read> var_rect: array<vec2<u32>>;
@group(0) @binding(21) var<storage, read_write> slabs: array<vec4<f32>>;
@group(0) @binding(22) var<storage, read> clean_image: array<vec4<f32>>;  // [K, H, W]

var<workgroup> s_list: vec4<u32>;   // (n virtual, insert position or 0xffffffff, removed position or 0xffffffff, 0)

// Lanes of the quad that a record takes part in (the same arithmetic and skip rules as
// blend_batch). A pixel that neither the clean nor the corrupted record reaches composites
// exactly as the clean frame did, so it is copied instead of re-blended.
fn contributes(xy: vec2<f32>, co: vec4<f32>, q: ptr<function, Quad>) -> vec4<bool> {
    return alpha_of(sigma_of(xy, co, q), co.w).hit;
}

// (key, index) ordering of the depth sort: depth bits, ties by primitive index.
fn before(ka: u32, ia: u32, kb: u32, ib: u32) -> bool {
    return ka < kb || (ka == kb && ia < ib);
}

fn clean_key(v: u32, g: u32) -> u32 {
    return bitcast<u32>(kv_rgb[v * rc.n_prims + g].w);
}

// number of list entries ordered before (key, idx)
fn count_before(v: u32, start: u32, end: u32, key: u32, idx: u32) -> u32 {
    var lo = start;
    var hi = end;
    let base = v * rc.capacity;
    while (lo < hi) {
        let mid = (lo + hi) >> 1u;
        let g = kv_isect[base + mid];
        if (before(clean_key(v, g), g, key, idx)) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - start;
}

@compute @workgroup_size(TILE, ROWS)
fn variants(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let e = linear_wg(wg, nwg);
    if (e >= rc.n_entries) {
        return;
    }
    let entry = entries[e];
    let b = entry.variant;
    let v = entry.view;
    let tile = entry.tile;
    let prim = entry.prim;
    let tx = tile % rc.tiles_x;
    let ty = tile / rc.tiles_x;
    let x = tx * TILE + lid.x;
    let y0 = ty * TILE + lid.y * QUAD;
    let inside = inside_quad(x, y0, rc.width, rc.height);
    var q = make_quad(x, y0, !inside);
    let range = kv_ranges[v * rc.n_tiles + tile];
    let vi = v * rc.n_variants + b;
    if (li == 0u) {
        atomicStore(&s_done, 0u);
        let n = range.y - range.x;
        // the clean entry of the corrupted primitive, if this tile lists it
        let ck = clean_key(v, prim);
        let qpos = count_before(v, range.x, range.y, ck, prim);
        var removed = 0xffffffffu;
        if (qpos < n && kv_isect[v * rc.capacity + range.x + qpos] == prim) {
            removed = qpos;
        }
        // the re-projected variant, if its rectangle covers this tile
        let r = var_rect[vi];
        var insert = 0xffffffffu;
        if ((r.x & 0xffffu) <= tx && tx < (r.y & 0xffffu) && (r.x >> 16u) <= ty && ty < (r.y >> 16u)) {
            var ip = count_before(v, range.x, range.y, bitcast<u32>(var_rgb[vi].w), prim);
            if (removed != 0xffffffffu && removed < ip) {
                ip = ip - 1u;
            }
            insert = ip;
        }
        var nv = n;
        if (removed != 0xffffffffu) { nv = nv - 1u; }
        if (insert != 0xffffffffu) { nv = nv + 1u; }
        s_list = vec4<u32>(nv, insert, removed, 0u);
    }
    let list = workgroupUniformLoad(&s_list);
    let nv = list.x;
    let insert = list.y;
    let removed = list.z;
    let o = v * rc.n_prims + prim;
    let old_hits = contributes(kv_xy[o], kv_conic[o], &q) & vec4<bool>(removed != 0xffffffffu);
    let new_hits = contributes(var_xy[vi], var_conic[vi], &q) & vec4<bool>(insert != 0xffffffffu);
    let copy_clean = inside & !old_hits & !new_hits;
    q.done = q.done | copy_clean;
    count_if_done(&q);
    let batches = (nv + BATCH - 1u) / BATCH;
    for (var bt = 0u; bt < batches; bt = bt + 1u) {
        for (var s = 0u; s < PER_LANE; s = s + 1u) {
            let i = bt * BATCH + s * LANES + li;
            if (i < nv) {
                if (i == insert) {
                    stage(s * LANES + li, var_xy[vi], var_conic[vi], var_rgb[vi]);
                } else {
                    var j = i;
                    if (insert != 0xffffffffu && i > insert) { j = j - 1u; }
                    if (removed != 0xffffffffu && j >= removed) { j = j + 1u; }
                    let g = kv_isect[v * rc.capacity + range.x + j];
                    let og = v * rc.n_prims + g;
                    stage(s * LANES + li, kv_xy[og], kv_conic[og], kv_rgb[og]);
                }
            }
        }
        workgroupBarrier();
        blend_batch(&q, min(BATCH, nv - bt * BATCH));
        if (all_done(li)) {
            break;
        }
    }
    let bg = rc.background.xyz;
    for (var i = 0u; i < QUAD; i = i + 1u) {
        var px = out_pixel(q, i, bg);
        if (copy_clean[i]) {
            px = clean_image[(v * rc.height + y0 + i) * rc.width + x];
        }
        slabs[e * TILE_PIXELS + (lid.y * QUAD + i) * TILE + lid.x] = px;
    }
}
