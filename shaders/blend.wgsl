// #import common

// Shared by the two full-frame compositors (both import it):
// composite.wgsl, 8 pixels per invocation in vec4 lanes and 32 invocations a tile (the shape for
// CPU Vulkan, docs/renderer.md), and composite_wide.wgsl, one pixel per invocation and 256 a tile
// (the shape GPUs fill). It holds the per-pixel rule, the staging of records through workgroup
// memory, the merge of chunks and the full-frame bindings. The per-pixel arithmetic is written
// once, over the lane types PF / PB / PU that each including stage declares (vec4<f32>,
// vec4<bool>, vec4<u32> there; f32, bool, u32 in the wide one) and `any_lane` (`any` of a
// vector; a scalar bool answers for itself, as SPIR-V's OpAny takes vectors only). Lanes are
// independent, so both compositors run the same operations in the same order on every pixel, and
// their frames and stop positions are the same bit for bit (tests/test_composite.py), and so are
// the pair boxes wherever the same long tiles find slab room: which ones do follows the order in
// which workgroups reach `list_long_tile`'s counter (any order is right, and a tile without room
// records FULL_BOX for more pairs, which only widens what the variants entry reads). A GPU driver
// may fuse multiply-adds in the scalar and the vec4 code differently: tools/bench.py compares
// the two shapes' frames bit for bit on every device it runs on.

// Renderer profile (docs/renderer.md, "Profiles"): PROFILE_STRICT (default) or PROFILE_GSPLAT.
override PROFILE: u32 = PROFILE_STRICT;

// ---- products kept out of multiply-adds ------------------------------------------------------
// SPIR-V lets a driver fuse a product into the add that consumes it (one rounding instead of two)
// unless the result is decorated NoContraction, which naga does not emit. NVIDIA's driver does,
// and not alike in the vec4 code of the lanes shape and the scalar code of composite_wide.wgsl:
// the two shapes' frames then differ in their last bits (docs/renderer.md "Measurements"). With UNFUSED (render/composite.py
// turns it on for GPU adapters; lavapipe fuses nothing) each such product passes through an XOR
// with `opaque_zero`, a zero the driver cannot see (every entry point loads it from its uniform's
// background.w, which the host sets to 0), so no add can absorb it: both shapes then round every
// product and every sum, in the same order, as lavapipe and the numpy twin do.
override UNFUSED: bool = false;
var<private> opaque_zero: u32;

fn unfused(x: PF) -> PF {
    if (UNFUSED) {
        return bitcast<PF>(bitcast<PU>(x) ^ PU(opaque_zero));
    }
    return x;
}

fn unfused_f32(x: f32) -> f32 {
    if (UNFUSED) {
        return bitcast<f32>(bitcast<u32>(x) ^ opaque_zero);
    }
    return x;
}

fn unfused_v3(x: vec3<f32>) -> vec3<f32> {
    if (UNFUSED) {
        return bitcast<vec3<f32>>(bitcast<vec3<u32>>(x) ^ vec3<u32>(opaque_zero));
    }
    return x;
}

const BATCH: u32 = TILE_PIXELS;             // records staged per batch
const FULL_BOX: u32 = (TILE - 1u) << 8u | (TILE - 1u) << 24u;
const EMPTY_BOX: u32 = 1u;                  // x0 = 1 > x1 = 0

var<workgroup> s_box: array<u32, BATCH>;          // x0 | x1 << 8 | y0 << 16 | y1 << 24 (inclusive)
var<workgroup> s_pos: array<vec4<f32>, BATCH>;    // mean x, mean y, cut, 0
var<workgroup> s_conic: array<vec4<f32>, BATCH>;  // conic, opacity
var<workgroup> s_rgb: array<vec4<f32>, BATCH>;
var<workgroup> s_done: atomic<u32>;  // invocations whose pixels have all finished
var<workgroup> s_all_done: u32;

// Pixels of one column held in lanes (one pixel in the wide shape): the column's centre x, each
// lane's row centre y (full-frame coordinates), their running colour and transmittance, and
// whether each has finished.
struct Quad {
    x: f32,
    y: PF,
    r: PF,
    g: PF,
    b: PF,
    T: PF,
    done: PB,
};

fn nan_lanes(v: PF) -> PB {
    return (bitcast<PU>(v) & PU(0x7fffffffu)) > PU(0x7f800000u);
}

// Half-extents (x, y) of the region outside which sigma > cut for certain, or +Inf (no bound).
// The minimum over dy of sigma(dx, dy) = 0.5 (A dx^2 + C dy^2) + B dx dy is 0.5 dx^2 D / C with
// D = A C - B^2, so |dx| >= sqrt(2 S C / D) gives sigma >= S; S = 1.01 max(cut, 1e-3) and a
// further 1% on the extent leave a margin of 3% in sigma. Only for bounded footprints
// (footprint_bounded, common.wgsl); otherwise +Inf.
fn reach_of(xy: vec2<f32>, co: vec4<f32>, cut: f32) -> vec2<f32> {
    if (!footprint_bounded(xy, co, cut)) {
        return vec2<f32>(inf_f32());
    }
    let A = co.x;
    let B = co.y;
    let C = co.z;
    let s = 2.02 * max(cut, 1e-3) / (unfused_f32(A * C) - unfused_f32(B * B));
    return 1.01 * sqrt(vec2<f32>(s * C, s * A));
}

// Tile-local pixel rectangle of a record (tile's first pixel at `origin`, full-frame
// coordinates): the columns and rows whose centres lie within `reach` of the mean, widened by
// one pixel for the rounding of dx = mx - px (<= 0.06 px here); EMPTY_BOX when none.
fn box_of(xy: vec2<f32>, co: vec4<f32>, cut: f32, origin: vec2<f32>) -> u32 {
    let reach = reach_of(xy, co, cut);
    if (!is_finite_f32(reach.x) || !is_finite_f32(reach.y)) {
        return FULL_BOX;
    }
    let last = f32(TILE - 1u);
    let lo = floor(xy - reach - origin - 0.5) - 1.0;
    let hi = ceil(xy + reach - origin - 0.5) + 1.0;
    if (hi.x < 0.0 || hi.y < 0.0 || lo.x > last || lo.y > last) {
        return EMPTY_BOX;
    }
    let l = vec2<u32>(max(lo, vec2<f32>(0.0)));
    let h = vec2<u32>(min(hi, vec2<f32>(last)));
    return l.x | (h.x << 8u) | (l.y << 16u) | (h.y << 24u);
}

// Stage one record (screen mean, conic + opacity, rgb) at slot i with its pixel box `bx`.
fn stage_boxed(i: u32, xy: vec2<f32>, co: vec4<f32>, rgb: vec4<f32>, bx: u32) {
    s_box[i] = bx;
    s_pos[i] = vec4<f32>(xy, cut_of(co.w), 0.0);
    s_conic[i] = co;
    s_rgb[i] = rgb;
}

// Stage one record at slot i for the tile at `origin`; returns its pixel box.
fn stage(i: u32, xy: vec2<f32>, co: vec4<f32>, rgb: vec4<f32>, origin: vec2<f32>) -> u32 {
    let bx = box_of(xy, co, cut_of(co.w), origin);
    stage_boxed(i, xy, co, rgb, bx);
    return bx;
}

// sigma of a record at the lanes' pixels, in the per-pixel rule's operation order.
fn sigma_of(xy: vec2<f32>, co: vec4<f32>, q: Quad) -> PF {
    let dx = xy.x - q.x;
    let dy = PF(xy.y) - q.y;
    return unfused(0.5 * (PF(unfused_f32(co.x * dx * dx)) + unfused(co.z * dy * dy))) + unfused((co.y * dx) * dy);
}

// alpha (NaN propagating) of a record at sigma, and whether each lane takes part in the blend.
struct Alpha {
    alpha: PF,
    hit: PB,
};

fn alpha_of(sigma: PF, o: f32) -> Alpha {
    let s_nan = nan_lanes(sigma);
    let x = -sigma;
    var e = exp(x);
    e = select(e, PF(0.0), x < PF(EXP_MIN));  // common.wgsl exp_ieee's rule
    e = select(e, PF(inf_f32()), x > PF(EXP_MAX));
    e = select(e, x, s_nan);
    let a = o * e;
    // a NaN alpha propagates (strict); gsplat: CUDA's min (fminf) drops the NaN
    let alpha = select(min(PF(0.99), a), select(a, PF(0.99), PROFILE == PROFILE_GSPLAT), nan_lanes(a));
    let skip = (!s_nan & (sigma < PF(0.0))) | (!nan_lanes(alpha) & (alpha < PF(1.0 / 255.0)));
    return Alpha(alpha, !skip);
}

// A staged record (mean and cut in st, conic and opacity in co, colour in rgb) blended into the lanes' pixels.
fn blend_quad(q0: Quad, st: vec4<f32>, co: vec4<f32>, rgb: vec4<f32>) -> Quad {
    var q = q0;
    let done = q.done;
    let sigma = sigma_of(st.xy, co, q);
    // lanes that skip for certain: sigma negative or past the cut
    let gone = !nan_lanes(sigma) & ((sigma < PF(0.0)) | (sigma > PF(st.z)));
    if (!any_lane(!done & !gone)) {
        return q;
    }
    let al = alpha_of(sigma, co.w);
    let alpha = al.alpha;
    let T = q.T;
    let hit = al.hit & !done;
    let next_t = T * (1.0 - alpha);
    let stop = hit & !nan_lanes(next_t) & (next_t <= PF(1e-4));
    let upd = hit & !stop;
    let w = alpha * T;
    q.r = select(q.r, q.r + unfused(rgb.x * w), upd);
    q.g = select(q.g, q.g + unfused(rgb.y * w), upd);
    q.b = select(q.b, q.b + unfused(rgb.z * w), upd);
    q.T = select(T, next_t, upd);
    q.done = done | stop;
    return q;
}

// After a batch: true (uniformly) when every invocation of the tile (LANES, the including
// stage's workgroup size) is finished.
fn all_done(li: u32) -> bool {
    workgroupBarrier();
    if (li == 0u) {
        s_all_done = atomicLoad(&s_done);
    }
    return workgroupUniformLoad(&s_all_done) == LANES;
}

// Pairs [a, b) of a tile list left unstaged (every pixel had finished): no pixel box known, so
// FULL_BOX for the variants entry (KEEP_BOXES frames).
fn unboxed(a: u32, b: u32, li: u32) {
    for (var idx = a + li; KEEP_BOXES && idx < b; idx = idx + LANES) {
        isect_box[idx] = FULL_BOX;
    }
}

// The start of a chunk's walk over pairs [a, b): s_done counts the invocations whose pixels have
// all finished (`done`); returns the batches to walk, 0 (uniformly) when every invocation has
// finished already (a later chunk of pixels that ended in chunk 0).
fn begin_range(a: u32, b: u32, li: u32, done: bool) -> u32 {
    if (li == 0u) {
        atomicStore(&s_done, 0u);
    }
    workgroupBarrier();
    if (done) {
        atomicAdd(&s_done, 1u);
    }
    if (all_done(li)) {
        unboxed(a, b, li);
        return 0u;
    }
    return (b - a + BATCH - 1u) / BATCH;
}

// ---- long tile lists: chunks merged front to back ---------------------------------------
// A tile list of n pairs is cut by list position into ceil(n / CHUNK_PAIRS) chunks; each chunk
// runs the per-pixel rule from C = 0, T = 1 (with its own early stop), and the chunks merge front
// to back per pixel (merge_quad, the one merge every path uses): the first chunk's (C, T) is taken
// as is, each later one as C = C + T * c, T = T * t, and a pixel ends (later chunks ignored) once
// a chunk stopped early at it or T <= 1e-4 after a merge (docs/renderer.md, "Long tile lists").

// Pairs per chunk (a multiple of BATCH); tests force small chunks on tiny scenes.
override CHUNK_PAIRS: u32 = CHUNK;
// Whether main and chunks leave the pairs' pixel boxes in isect_box: only a frame kept for the
// incremental re-compositor needs them (render/renderer.py capture_views).
override KEEP_BOXES: bool = true;
// Whether the frames were binned exactly (bin.wgsl EXACT_BIN): composite.wgsl's variants entry
// pairs a variant record with a tile as the binning would, and its main and chunks mask the
// quadrants a record's ellipse cannot reach (ellipse_quadrants; otherwise its pixel box alone
// decides). composite_wide.wgsl does not read it: each pixel tests the record's box.
override EXACT_BIN: bool = true;

// A chunk's pixels (c, t, stopped) merged into the pixels' running (C, T, ended) `acc`.
fn merge_quad(acc: Quad, c: Quad, first: bool) -> Quad {
    var q = acc;
    if (first) {
        q.r = c.r;
        q.g = c.g;
        q.b = c.b;
        q.T = c.T;
        q.done = acc.done | c.done;
        return q;
    }
    let live = !acc.done;
    let T = acc.T;
    let t = T * c.T;
    q.r = select(acc.r, acc.r + unfused(T * c.r), live);
    q.g = select(acc.g, acc.g + unfused(T * c.g), live);
    q.b = select(acc.b, acc.b + unfused(T * c.b), live);
    q.T = select(T, t, live);
    q.done = acc.done | (live & (c.done | (!nan_lanes(t) & (t <= PF(1e-4)))));
    return q;
}

// ---- full frame -----------------------------------------------------------------------------
@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> isect_prims: array<u32>;
@group(0) @binding(3) var<storage, read> proj_xy: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> proj_conic: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> proj_rgb: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> image: array<vec4<f32>>;
// The pixel box of every pair (FULL_BOX past the point where its chunk stopped): the variants
// entry reads the clean frame's copy instead of re-reading records that cannot reach its pixels.
@group(0) @binding(7) var<storage, read_write> isect_box: array<u32>;

// The work main lists for the later passes (zeroed before main, render/composite.py): slab slots
// taken, later chunks listed, long tiles listed, and the indirect dispatch arguments of `chunks`
// (byte 16) and `merge` (byte 32): min(listed, MAX_GROUPS_X) workgroups, each striding the list.
struct Work {
    slots: atomic<u32>,
    extra: atomic<u32>,
    merges: atomic<u32>,
    pad0: u32,
    extra_groups: atomic<u32>,
    extra_y: u32,
    extra_z: u32,
    pad1: u32,
    merge_groups: atomic<u32>,
    merge_y: u32,
    merge_z: u32,
    pad2: u32,
};

@group(0) @binding(30) var<storage, read_write> work: Work;
// One slot of TILE x TILE (c.rgb, t) per chunk of a long tile; t is stored negated where the chunk
// stopped early (t > 1e-4 there, so the sign is free; a NaN t never stops).
@group(0) @binding(31) var<storage, read_write> chunk_slabs: array<vec4<f32>>;
@group(0) @binding(32) var<storage, read_write> extra_list: array<vec4<u32>>;  // tile, chunk, slot, 0
@group(0) @binding(33) var<storage, read_write> merge_list: array<vec2<u32>>;  // tile, first slot
// the same buffer as `work`, read-only: the later passes also take their indirect arguments from it
@group(0) @binding(34) var<storage, read> work_counts: array<u32>;

var<workgroup> s_work: vec4<u32>;
const VOID: u32 = 0xffffffffu;  // an extra_list item of a tile composited in main

// A tile of n_chunks > 1 chunks (main, after its chunk 0): take its slab slots and work items,
// list its merge (for `merge`) and its later chunks (for `chunks`); returns (first slot, first
// work item, 1 if they fit, 0), uniform. Where they do not fit (only where the ranges list more
// pairs than the capacity, e.g. a flipped range) its items are void, and the caller composites its
// chunks in sequence on its own workgroup.
fn list_long_tile(tile: u32, n_chunks: u32, li: u32) -> vec4<u32> {
    if (li == 0u) {
        let slot = atomicAdd(&work.slots, n_chunks);
        let at = atomicAdd(&work.extra, n_chunks - 1u);
        atomicMax(&work.extra_groups, min(at + n_chunks - 1u, MAX_GROUPS_X));
        let fits = slot + n_chunks <= arrayLength(&chunk_slabs) / TILE_PIXELS
            && at + n_chunks - 1u <= arrayLength(&extra_list);
        if (fits) {
            let m = atomicAdd(&work.merges, 1u);
            atomicMax(&work.merge_groups, min(m + 1u, MAX_GROUPS_X));
            merge_list[m] = vec2<u32>(tile, slot);
        }
        s_work = vec4<u32>(slot, at, u32(fits), 0u);
    }
    let w = workgroupUniformLoad(&s_work);
    if (w.z == 0u) {
        for (var e = w.y + li; e < min(w.y + n_chunks - 1u, arrayLength(&extra_list)); e = e + LANES) {
            extra_list[e] = vec4<u32>(VOID, 0u, 0u, 0u);
        }
    } else {
        for (var c = 1u + li; c < n_chunks; c = c + LANES) {
            extra_list[w.y + c - 1u] = vec4<u32>(tile, c, w.x + c, 0u);
        }
    }
    return w;
}

// KEEP_BOXES frames: per pixel, the position in its tile's list of the record it stopped at, or
// NEVER (it never stopped, or its list is longer than a chunk), as the image is indexed.
const NEVER: u32 = 0xffffffffu;
@group(0) @binding(35) var<storage, read_write> stop_pos: array<u32>;

// The first pixel of tile (tx, ty) in full-frame coordinates (a sort-first viewport starts at
// `origin`).
fn tile_first(tx: u32, ty: u32) -> vec2<u32> {
    return vec2<u32>(bin.origin & 0xffffu, bin.origin >> 16u) + vec2<u32>(tx * TILE, ty * TILE);
}

// The frame of the tile being composited, among the `bin.views` frames of the list (batched views,
// render/renderer.py; 0 otherwise): tile ids are frame * n_tiles + ty * tiles_x + tx.
var<private> frame_view: u32;

// Enter tile id `tile`: sets frame_view, returns the tile's (tx, ty) in its frame.
fn enter_tile(tile: u32) -> vec2<u32> {
    frame_view = tile / bin.n_tiles;
    let t = tile % bin.n_tiles;
    return vec2<u32>(t % bin.tiles_x, t / bin.tiles_x);
}

// Where pixel (x, y) of the tile's frame (viewport coordinates) lies in `image` and `stop_pos`.
fn image_index(x: u32, y: u32) -> u32 {
    return ((bin.frame + frame_view) * bin.height + y) * bin.width + x;
}
