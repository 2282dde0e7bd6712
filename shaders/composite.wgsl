// Front-to-back compositing (render/composite.py): one TILE x TILE workgroup per tile,
// intersections staged through workgroup memory in batches of TILE_PIXELS. Rules (skips,
// NaN-propagating min, early stop) are in docs/renderer.md. Output pixel = (C + T * background, T).
//
// Two entry points share the blending code, so their arithmetic is identical bit for bit:
// - main: a tile of a full frame;
// - variants: a tile of a single-upset variant, re-composited from the clean frame's tile list
//   with the corrupted primitive removed and its re-projected record merged in at its depth
//   (render/incremental.py; equal to a full re-render bit for bit).

// Renderer profile (docs/renderer.md, "Profiles"): PROFILE_STRICT (default) or PROFILE_GSPLAT.
override PROFILE: u32 = PROFILE_STRICT;

var<workgroup> s_xy: array<vec2<f32>, TILE_PIXELS>;
var<workgroup> s_conic: array<vec4<f32>, TILE_PIXELS>;
var<workgroup> s_rgb: array<vec4<f32>, TILE_PIXELS>;
var<workgroup> s_done: atomic<u32>;
var<workgroup> s_all_done: u32;

struct Pixel {
    pix: vec2<f32>,
    C: vec3<f32>,
    T: f32,
    done: bool,
};

fn begin_pixel(li: u32, inside: bool, px: u32, py: u32) -> Pixel {
    if (li == 0u) {
        atomicStore(&s_done, 0u);
        s_all_done = 0u;
    }
    workgroupBarrier();
    if (!inside) {
        atomicAdd(&s_done, 1u);
    }
    return Pixel(vec2<f32>(f32(px) + 0.5, f32(py) + 0.5), vec3<f32>(0.0), 1.0, !inside);
}

// Blend the m staged intersections into one pixel.
fn blend_batch(px: ptr<function, Pixel>, m: u32) {
    if ((*px).done) {
        return;
    }
    var T = (*px).T;
    var C = (*px).C;
    for (var k = 0u; k < m; k = k + 1u) {
        let co = s_conic[k];
        let d = s_xy[k] - (*px).pix;
        let sigma = 0.5 * (co.x * d.x * d.x + co.z * d.y * d.y) + co.y * d.x * d.y;
        // NaN never takes a skip or stop branch: it must reach the pixel (bit tests, since
        // compilers may assume finite math).
        if (!is_nan_f32(sigma) && sigma < 0.0) {
            continue;
        }
        let a = co.w * exp_ieee(-sigma);
        var alpha = a;
        if (!is_nan_f32(a)) {
            alpha = min(0.99, a);
        } else if (PROFILE == PROFILE_GSPLAT) {
            alpha = 0.99;  // gsplat: CUDA's min (fminf) drops the NaN
        }
        if (!is_nan_f32(alpha) && alpha < 1.0 / 255.0) {
            continue;
        }
        let next_t = T * (1.0 - alpha);
        if (!is_nan_f32(next_t) && next_t <= 1e-4) {
            (*px).done = true;
            atomicAdd(&s_done, 1u);
            break;
        }
        C = C + s_rgb[k].xyz * (alpha * T);
        T = next_t;
    }
    (*px).T = T;
    (*px).C = C;
}

// After a batch: true (uniformly) when every pixel of the tile is finished.
fn all_done(li: u32) -> bool {
    workgroupBarrier();
    if (li == 0u) {
        s_all_done = atomicLoad(&s_done);
    }
    return workgroupUniformLoad(&s_all_done) == TILE_PIXELS;
}

// ---- full frame -----------------------------------------------------------------------------
@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> isect_prims: array<u32>;
@group(0) @binding(3) var<storage, read> proj_xy: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> proj_conic: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> proj_rgb: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> image: array<vec4<f32>>;

@compute @workgroup_size(TILE, TILE)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let tile = wg.y * bin.tiles_x + wg.x;
    let px = wg.x * TILE + lid.x;
    let py = wg.y * TILE + lid.y;
    let inside = px < bin.width && py < bin.height;
    // pixel centres in full-frame coordinates (a sort-first region starts at `origin`)
    var p = begin_pixel(li, inside, px + (bin.origin & 0xffffu), py + (bin.origin >> 16u));
    let range = ranges[tile];
    let n = range.y - range.x;
    let batches = (n + TILE_PIXELS - 1u) / TILE_PIXELS;
    for (var b = 0u; b < batches; b = b + 1u) {
        let idx = range.x + b * TILE_PIXELS + li;
        if (idx < range.y) {
            let g = isect_prims[idx];
            s_xy[li] = proj_xy[g];
            s_conic[li] = proj_conic[g];
            s_rgb[li] = proj_rgb[g];
        }
        workgroupBarrier();
        blend_batch(&p, min(TILE_PIXELS, n - b * TILE_PIXELS));
        if (all_done(li)) {
            break;
        }
    }
    if (inside) {
        image[(bin.stats_index * bin.height + py) * bin.width + px] = vec4<f32>(p.C + p.T * bin.background.xyz, p.T);
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

// Whether a record takes part in a pixel's blend (the same arithmetic and skip rules as
// blend_batch). A pixel that neither the clean nor the corrupted record reaches composites
// exactly as the clean frame did, so it is copied instead of re-blended.
fn contributes(xy: vec2<f32>, co: vec4<f32>, pix: vec2<f32>) -> bool {
    let d = xy - pix;
    let sigma = 0.5 * (co.x * d.x * d.x + co.z * d.y * d.y) + co.y * d.x * d.y;
    if (!is_nan_f32(sigma) && sigma < 0.0) {
        return false;
    }
    let a = co.w * exp_ieee(-sigma);
    var alpha = a;
    if (!is_nan_f32(a)) {
        alpha = min(0.99, a);
    }
    return !(!is_nan_f32(alpha) && alpha < 1.0 / 255.0);
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

@compute @workgroup_size(TILE, TILE)
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
    let px = tx * TILE + lid.x;
    let py = ty * TILE + lid.y;
    let inside = px < rc.width && py < rc.height;
    var p = begin_pixel(li, inside, px, py);
    let range = kv_ranges[v * rc.n_tiles + tile];
    let vi = v * rc.n_variants + b;
    if (li == 0u) {
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
    var copy_clean = false;
    if (inside) {
        let o = v * rc.n_prims + prim;
        let old_hits = removed != 0xffffffffu && contributes(kv_xy[o], kv_conic[o], p.pix);
        let new_hits = insert != 0xffffffffu && contributes(var_xy[vi], var_conic[vi], p.pix);
        if (!old_hits && !new_hits) {
            copy_clean = true;
            p.done = true;
            atomicAdd(&s_done, 1u);
        }
    }
    let batches = (nv + TILE_PIXELS - 1u) / TILE_PIXELS;
    for (var bt = 0u; bt < batches; bt = bt + 1u) {
        let i = bt * TILE_PIXELS + li;
        if (i < nv) {
            if (i == insert) {
                s_xy[li] = var_xy[vi];
                s_conic[li] = var_conic[vi];
                s_rgb[li] = var_rgb[vi];
            } else {
                var j = i;
                if (insert != 0xffffffffu && i > insert) { j = j - 1u; }
                if (removed != 0xffffffffu && j >= removed) { j = j + 1u; }
                let g = kv_isect[v * rc.capacity + range.x + j];
                let o = v * rc.n_prims + g;
                s_xy[li] = kv_xy[o];
                s_conic[li] = kv_conic[o];
                s_rgb[li] = kv_rgb[o];
            }
        }
        workgroupBarrier();
        blend_batch(&p, min(TILE_PIXELS, nv - bt * TILE_PIXELS));
        if (all_done(li)) {
            break;
        }
    }
    if (copy_clean) {
        slabs[e * TILE_PIXELS + li] = clean_image[(v * rc.height + py) * rc.width + px];
    } else {
        slabs[e * TILE_PIXELS + li] = vec4<f32>(p.C + p.T * rc.background.xyz, p.T);
    }
}
