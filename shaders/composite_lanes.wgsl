// #import blend

// The "lanes" compositor shape's pixels (render/composite.py, Compositing(shape="lanes"), the
// shape for CPU Vulkan): the functions composite_frame.wgsl requires of a compositor, written
// over vec4 lanes, and shared by composite.wgsl (main, chunks, merge) and variants.wgsl.
// Each invocation composites a column of QPI x QUAD (2 x 4) pixels, held as vec4 lanes (one Quad
// per 4 rows): a staged record is read once for eight pixels, and the workgroup has 8x fewer
// invocations to switch between at barriers (CPU Vulkan runs a workgroup's invocations in SIMD
// groups, and gathers every per-invocation workgroup-memory read). Intersections are staged
// through workgroup memory in batches of BATCH records. Rules (skips, NaN-propagating min, early
// stop) are in docs/renderer.md. Output pixel = (C + T * background, T).
//
// Exactness: every pixel runs the per-pixel rule with the same operations in the same order as a
// one-pixel-per-invocation loop (lanes are independent; skips and stops are masks), so the image
// is the same bit for bit. Four shortcuts skip only work that cannot change a pixel:
// - `cut`: a sigma beyond which alpha < 1/255 for certain (from the opacity o: ln(255 o) + 0.01,
//   a margin far above exp's error; -Inf when o < 0.001, where alpha < 1/255 for every
//   sigma >= 0; +Inf, never cut, when o is NaN or |o| > 1e30): lanes past it skip without exp;
// - `box`: the tile-local pixel rectangle outside which sigma > cut for certain (below), so an
//   invocation or a quad of the variants entry outside it skips the record after one integer test
//   (main and chunks fold it into the quadrant masks below);
// - an invocation whose pixels have all stopped leaves the batch loop; the workgroup leaves the
//   tile when all of them have;
// - `main` and `chunks` stage each invocation's PER_LANE consecutive slots with one bit per slot and quadrant
//   (8 x 8 pixels; an invocation's pixels lie in one) saying whether the record may reach it (its
//   box meets the quadrant and, with exact binning, its ellipse reaches one of the quadrant's pixel
//   centres), so an invocation visits only the records of its quadrant, in list order (the others
//   skip all its pixels anyway): on CPU Vulkan, where a quadrant is one SIMD group and a branch
//   never skips code, the number of such visits is what compositing costs.
//
// The per-pixel rule, staging, the merge of chunks and the full-frame bindings are in blend.wgsl
// (shared with composite_wide.wgsl, one pixel per invocation, for GPUs); here the lanes are vec4.

alias PF = vec4<f32>;
alias PB = vec4<bool>;
alias PU = vec4<u32>;

fn any_lane(b: PB) -> bool {
    return any(b);
}

const QUAD: u32 = 4u;                       // pixels per Quad (vec4 lanes, one column)
const QPI: u32 = 2u;                        // Quads per invocation (2 written out in blend_quads)
const SPAN: u32 = QUAD * QPI;               // rows per invocation
const ROWS: u32 = TILE / SPAN;              // invocation rows per tile
const LANES: u32 = TILE * ROWS;             // invocations per workgroup
const PER_LANE: u32 = BATCH / LANES;        // records each invocation stages per batch

// Per quadrant (8 x 8 pixels; an invocation's pixels lie in one), per staging invocation: which of
// its PER_LANE consecutive slots hold a record whose pixel box meets the quadrant (bit s).
var<workgroup> s_qmask: array<u32, 4 * LANES>;

// The invocation's pixels: column x, rows y0 .. y0 + SPAN - 1 (full-frame coordinates), Quad j
// holding rows y0 + QUAD j ..; `inside` says which lie in the viewport (w x h from `first`, the
// viewport's first pixel); the others are done from the start.
struct Pixels {
    q: array<Quad, QPI>,
};

alias Stops = array<vec4<u32>, QPI>;      // their stop positions (composite_frame.wgsl)

fn make_pixels(x: u32, y0: u32, first: vec2<u32>, size: vec2<u32>) -> Pixels {
    var p: Pixels;
    for (var j = 0u; j < QPI; j = j + 1u) {
        let ys = vec4<u32>(y0 + QUAD * j) + vec4<u32>(0u, 1u, 2u, 3u);
        let inside = vec4<bool>(x - first.x < size.x) & (ys - vec4<u32>(first.y) < vec4<u32>(size.y));
        let yf = vec4<f32>(ys) + 0.5;
        p.q[j] = Quad(f32(x) + 0.5, yf, vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(1.0), !inside);
    }
    return p;
}

fn all_pixels_done(p: ptr<function, Pixels>) -> bool {
    return all((*p).q[0].done) && all((*p).q[1].done);  // QPI = 2
}

// Count an invocation whose pixels are all finished before the first batch (after s_done's reset
// and a barrier).
fn count_if_done(p: ptr<function, Pixels>) {
    if (all_pixels_done(p)) {
        atomicAdd(&s_done, 1u);
    }
}

// Staged record k blended into the invocation's quads that its rows y0..y1 reach (QPI = 2 written
// out: CPU Vulkan does not unroll a loop over the private array; docs/renderer.md "Measurements").
fn blend_quads(p: ptr<function, Pixels>, st: vec4<f32>, co: vec4<f32>, k: u32, row0: u32, y0: u32, y1: u32) {
    let rgb = s_rgb[k];
    if (row0 + QUAD - 1u >= y0 && row0 <= y1) {
        (*p).q[0] = blend_quad((*p).q[0], st, co, rgb);
    }
    if (row0 + 2u * QUAD - 1u >= y0 && row0 + QUAD <= y1) {
        (*p).q[1] = blend_quad((*p).q[1], st, co, rgb);
    }
}

// Staged record k blended into the invocation's pixels (tile-local column `col`, first row
// `row0`) where its box reaches them; true (and counted in s_done) once they have all stopped.
fn blend_record(p: ptr<function, Pixels>, col: u32, row0: u32, k: u32) -> bool {
    let bx = s_box[k];
    let y0 = (bx >> 16u) & 0xffu;
    let y1 = bx >> 24u;
    if (col < (bx & 0xffu) || col > ((bx >> 8u) & 0xffu) || row0 + SPAN - 1u < y0 || row0 > y1) {
        return false;
    }
    blend_quads(p, s_pos[k], s_conic[k], k, row0, y0, y1);
    if (all_pixels_done(p)) {
        atomicAdd(&s_done, 1u);
        return true;
    }
    return false;
}

// Blend the m staged records into the invocation's pixels.
fn blend_batch(p: ptr<function, Pixels>, col: u32, row0: u32, m: u32) {
    if (all_pixels_done(p)) {
        return;
    }
    for (var k = 0u; k < m; k = k + 1u) {
        if (blend_record(p, col, row0, k)) {
            break;
        }
    }
}

// Bit q (0..3) set when pixel box bx meets quadrant q: columns 8 (q % 2) .. + 7, rows 8 (q / 2) .. + 7.
fn quadrants(bx: u32) -> u32 {
    let h = TILE / 2u;
    let x0 = bx & 0xffu;
    let x1 = (bx >> 8u) & 0xffu;
    let y0 = (bx >> 16u) & 0xffu;
    let y1 = bx >> 24u;
    if (x0 > x1 || y0 > y1) {
        return 0u;
    }
    let xs = select(0u, 1u, x0 < h) | select(0u, 2u, x1 >= h);
    let ys = select(0u, 1u, y0 < h) | select(0u, 2u, y1 >= h);
    return (xs * select(0u, 1u, (ys & 1u) != 0u)) | ((xs << 2u) * select(0u, 1u, (ys & 2u) != 0u));
}

// Bit q (as `quadrants`) set when the record's footprint, exact binning's margined ellipse
// (common.wgsl reach, band_extent), may reach a pixel centre of quadrant q of the tile whose first
// pixel is `origin` (full frame); all four for a record without a bound. The ellipse is tighter
// than the pixel box (fewer record visits per quadrant: docs/renderer.md "Measurements").
fn ellipse_quadrants(xy: vec2<f32>, co: vec4<f32>, origin: vec2<f32>) -> u32 {
    let r = reach(xy, co);
    if (r.kind == REACH_ALL) {
        return 15u;
    }
    let h = f32(TILE / 2u);
    var q = 0u;
    for (var j = 0u; j < 2u; j = j + 1u) {
        let y0 = origin.y + f32(j) * h + 0.5;
        let e = band_extent(r, y0, y0 + h - 1.0);
        let hit = r.kind == REACH_ELLIPSE && e.x <= e.y;
        let left = hit && e.x <= origin.x + h - 0.5 && e.y >= origin.x + 0.5;
        let right = hit && e.x <= origin.x + 2.0 * h - 0.5 && e.y >= origin.x + h + 0.5;
        q = q | (select(0u, 1u, left) | select(0u, 2u, right)) << (2u * j);
    }
    return q;
}

// Record the quadrant masks of the invocation's PER_LANE consecutive slots (quadrant bits in qs).
fn write_qmask(li: u32, qs: array<u32, PER_LANE>) {
    var m = vec4<u32>(0u);
    for (var s = 0u; s < PER_LANE; s = s + 1u) {
        let q = qs[s];
        m = m | (vec4<u32>((vec4<u32>(q) >> vec4<u32>(0u, 1u, 2u, 3u)) & vec4<u32>(1u)) << vec4<u32>(s));
    }
    s_qmask[li] = m.x;
    s_qmask[LANES + li] = m.y;
    s_qmask[2u * LANES + li] = m.z;
    s_qmask[3u * LANES + li] = m.w;
}

// blend_batch over the staged records that may reach the invocation's quadrant q only (in slot
// order, which is list order): the others skip all its pixels for certain. The quadrant's records
// are blended into both Quads without the box test of blend_record: on CPU Vulkan a branch never
// skips code (docs/renderer.md), so the test only costs (docs/renderer.md "Measurements"), and a
// pixel past the cut still skips the record without exp.
// KEEP_BOXES: `stops` receives the list position (slot k at base + k) of the record each pixel
// stopped at (the incremental re-compositor copies pixels that a change behind it cannot reach).
fn blend_batch_masked(p: ptr<function, Pixels>, q: u32, base: u32, stops: ptr<function, Stops>) {
    if (all_pixels_done(p)) {
        return;
    }
    for (var w = 0u; w < LANES; w = w + 1u) {
        var bits = s_qmask[q * LANES + w];
        while (bits != 0u) {
            let k = w * PER_LANE + firstTrailingBit(bits);
            bits = bits & (bits - 1u);
            let st = s_pos[k];
            let co = s_conic[k];
            let rgb = s_rgb[k];
            let done0 = (*p).q[0].done;
            let done1 = (*p).q[1].done;
            (*p).q[0] = blend_quad((*p).q[0], st, co, rgb);
            (*p).q[1] = blend_quad((*p).q[1], st, co, rgb);  // QPI = 2
            if (KEEP_BOXES) {
                (*stops)[0] = select((*stops)[0], vec4<u32>(base + k), (*p).q[0].done & !done0);
                (*stops)[1] = select((*stops)[1], vec4<u32>(base + k), (*p).q[1].done & !done1);
            }
            if (all_pixels_done(p)) {
                atomicAdd(&s_done, 1u);
                return;
            }
        }
    }
}

// Pixel i of a quad as the output (C + T * background, T).
fn out_pixel(q: Quad, i: u32, bg: vec3<f32>) -> vec4<f32> {
    let T = q.T[i];
    return vec4<f32>(vec3<f32>(q.r[i], q.g[i], q.b[i]) + unfused_v3(T * bg), T);
}

fn merge_pixels(acc: ptr<function, Pixels>, c: ptr<function, Pixels>, first: bool) {
    for (var j = 0u; j < QPI; j = j + 1u) {
        (*acc).q[j] = merge_quad((*acc).q[j], (*c).q[j], first);
    }
}

// Composite the pairs [a, b) of the tile at `origin` (one chunk) into p, leaving every pair's
// pixel box in isect_box (FULL_BOX for those never staged).
fn composite_range(p: ptr<function, Pixels>, a: u32, b: u32, origin: vec2<f32>, col: u32, row0: u32, li: u32,
                   pos0: u32, stops: ptr<function, Stops>) {
    let batches = begin_range(a, b, li, all_pixels_done(p));
    for (var bt = 0u; bt < batches; bt = bt + 1u) {
        var quads: array<u32, PER_LANE>;
        for (var s = 0u; s < PER_LANE; s = s + 1u) {
            let i = li * PER_LANE + s;
            let idx = a + bt * BATCH + i;
            quads[s] = 0u;
            if (idx < b) {
                let g = isect_prims[idx];
                let xy = proj_xy[g];
                let co = proj_conic[g];
                let bx = stage(i, xy, co, proj_rgb[g], origin);
                quads[s] = quadrants(bx);
                if (EXACT_BIN) { quads[s] = quads[s] & ellipse_quadrants(xy, co, origin); }
                if (KEEP_BOXES) { isect_box[idx] = bx; }
            }
        }
        write_qmask(li, quads);
        workgroupBarrier();
        blend_batch_masked(p, col / (TILE / 2u) + 2u * (row0 / (TILE / 2u)), pos0 + bt * BATCH, stops);
        if (all_done(li)) {
            unboxed(a + (bt + 1u) * BATCH, b, li);
            break;
        }
    }
}

// Where pixel (Quad j, lane i) of the invocation at column `col`, rows row0 .., lies in slot
// `slot` of an array of TILE x TILE pixel states (a chunk's slab, a variant's slab, a
// checkpoint, a chunk's clean result).
fn slot_pixel(slot: u32, col: u32, row0: u32, j: u32, i: u32) -> u32 {
    return slot * TILE_PIXELS + (row0 + QUAD * j + i) * TILE + col;
}

// A chunk's pixels into slab `slot` (t negated where stopped: done lanes outside the viewport are
// never merged).
fn write_slab(p: ptr<function, Pixels>, slot: u32, col: u32, row0: u32) {
    for (var j = 0u; j < QPI; j = j + 1u) {
        let q = (*p).q[j];
        let t = select(q.T, -q.T, q.done);
        for (var i = 0u; i < QUAD; i = i + 1u) {
            chunk_slabs[slot_pixel(slot, col, row0, j, i)] = vec4<f32>(q.r[i], q.g[i], q.b[i], t[i]);
        }
    }
}

fn read_slab(slot: u32, col: u32, row0: u32, p0: Pixels) -> Pixels {
    var p = p0;
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            p.q[j] = with_lane_state(p.q[j], i, chunk_slabs[slot_pixel(slot, col, row0, j, i)]);
        }
        let t = p.q[j].T;
        let stopped = t < vec4<f32>(0.0);
        p.q[j].T = select(t, -t, stopped);
        p.q[j].done = stopped;
    }
    return p;
}

// One lane's running (rgb, T) as a state array holds it, and back (every array of TILE x TILE
// states: chunk results, checkpoints, a variant's slab).
fn lane_state(q: Quad, i: u32) -> vec4<f32> {
    return vec4<f32>(q.r[i], q.g[i], q.b[i], q.T[i]);
}

fn with_lane_state(q0: Quad, i: u32, v: vec4<f32>) -> Quad {
    var q = q0;
    q.r[i] = v.x;
    q.g[i] = v.y;
    q.b[i] = v.z;
    q.T[i] = v.w;
    return q;
}

// The viewport's pixels of a tile (tile-local column `col`, rows row0 ..) into the image.
fn write_image(p: ptr<function, Pixels>, tx: u32, ty: u32, col: u32, row0: u32) {
    let bg = bin.background.xyz;
    let x = tx * TILE + col;
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            let y = ty * TILE + row0 + QUAD * j + i;
            if (x < bin.width && y < bin.height) {
                image[image_index(x, y)] = out_pixel((*p).q[j], i, bg);
            }
        }
    }
}

fn no_stops() -> Stops {
    return Stops(vec4<u32>(NEVER), vec4<u32>(NEVER));
}

// KEEP_BOXES frames: the list positions of the records the pixels stopped at (NEVER: none, or a
// list longer than a chunk), indexed as the image.
fn write_stops(stops: ptr<function, Stops>, tx: u32, ty: u32, col: u32, row0: u32) {
    if (!KEEP_BOXES) {
        return;
    }
    let x = tx * TILE + col;
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            let y = ty * TILE + row0 + QUAD * j + i;
            if (x < bin.width && y < bin.height) {
                stop_pos[image_index(x, y)] = (*stops)[j][i];
            }
        }
    }
}

// A later chunk's start: the pixels' positions and ended lanes, C = 0, T = 1.
fn restart(acc: ptr<function, Pixels>) -> Pixels {
    var p: Pixels;
    for (var j = 0u; j < QPI; j = j + 1u) {
        let a = (*acc).q[j];
        p.q[j] = Quad(a.x, a.y, vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(1.0), a.done);
    }
    return p;
}

// Pixels that ended in `first` (a tile's chunk 0, read back from its slab) stay ended.
fn keep_ended(p: ptr<function, Pixels>, first: Pixels) {
    for (var j = 0u; j < QPI; j = j + 1u) {
        (*p).q[j].done = (*p).q[j].done | first.q[j].done;
    }
}

fn tile_pixels(tx: u32, ty: u32, col: u32, row0: u32) -> Pixels {
    let tile0 = tile_first(tx, ty);
    let first = vec2<u32>(bin.origin & 0xffffu, bin.origin >> 16u);
    return make_pixels(tile0.x + col, tile0.y + row0, first, vec2<u32>(bin.width, bin.height));
}
