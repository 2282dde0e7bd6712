// #import blend
// #import composite_frame

// Full-frame compositing in the shape GPUs fill (render/composite.py, Compositing(shape="wide")):
// one pixel per invocation and one TILE x TILE workgroup (256 invocations) a tile, as GPU
// rasterizers do (gsplat, the INRIA rasterizer). composite.wgsl's main and chunks give each of 32
// invocations 8 pixels, the right shape for CPU Vulkan, but one warp a tile on a GPU: 1,024 tiles
// fill about an eighth of an H200's thread slots (docs/renderer.md). The tiles, chunks, slabs and
// work lists are blend.wgsl's and the entry points main and chunks composite_frame.wgsl's, shared
// with composite.wgsl, whose `merge` blends long tiles' slabs.
//
// Each invocation stages one record of a batch of BATCH (blend.wgsl stage), then visits the
// batch's records in list order, blending those whose pixel box holds its pixel with blend.wgsl's
// blend_quad over scalar lanes. A record whose box misses a pixel skips it for certain (the box
// bounds sigma <= cut), as does one that composite.wgsl's quadrant masks leave out, so the two
// compositors blend the same records into every pixel with the same operations in the same
// order: frames, slabs, stop positions and pair boxes are the same bit for bit
// (tests/test_composite.py). An invocation whose pixel has stopped leaves the batch loop; the
// workgroup leaves the tile when all have.

alias PF = f32;
alias PB = bool;
alias PU = u32;

fn any_lane(b: PB) -> bool {
    return b;
}

const LANES: u32 = TILE_PIXELS;  // invocations per workgroup: one a pixel
const SPAN: u32 = 1u;            // rows per invocation
const ROWS: u32 = TILE;          // invocation rows per tile

alias Stops = u32;               // the pixel's stop position (composite_frame.wgsl)

// Pixel (x, y) (full-frame coordinates), done from the start outside the viewport (w x h from
// `first`, its first pixel).
fn make_pixel(x: u32, y: u32, first: vec2<u32>, size: vec2<u32>) -> Quad {
    let inside = x - first.x < size.x && y - first.y < size.y;
    return Quad(f32(x) + 0.5, f32(y) + 0.5, 0.0, 0.0, 0.0, 1.0, !inside);
}

fn tile_pixels(tx: u32, ty: u32, col: u32, row: u32) -> Quad {
    let tile0 = tile_first(tx, ty);
    let first = vec2<u32>(bin.origin & 0xffffu, bin.origin >> 16u);
    return make_pixel(tile0.x + col, tile0.y + row, first, vec2<u32>(bin.width, bin.height));
}

// The m staged records blended into the pixel (tile-local column `col`, row `row`) where their
// boxes hold it; KEEP_BOXES: `stop` receives the list position (base + k) of the record it
// stopped at.
fn blend_batch(p: ptr<function, Quad>, col: u32, row: u32, m: u32, base: u32, stop: ptr<function, u32>) {
    if ((*p).done) {
        return;
    }
    for (var k = 0u; k < m; k = k + 1u) {
        let bx = s_box[k];
        if (col < (bx & 0xffu) || col > ((bx >> 8u) & 0xffu) || row < ((bx >> 16u) & 0xffu) || row > (bx >> 24u)) {
            continue;
        }
        *p = blend_quad(*p, s_pos[k], s_conic[k], s_rgb[k]);
        if ((*p).done) {
            if (KEEP_BOXES) {
                *stop = base + k;
            }
            atomicAdd(&s_done, 1u);
            return;
        }
    }
}

// Composite the pairs [a, b) of the tile at `origin` (one chunk) into p, leaving every pair's
// pixel box in isect_box (FULL_BOX for those never staged), as composite.wgsl composite_range.
fn composite_range(p: ptr<function, Quad>, a: u32, b: u32, origin: vec2<f32>, col: u32, row: u32, li: u32,
                   pos0: u32, stop: ptr<function, u32>) {
    let batches = begin_range(a, b, li, (*p).done);
    for (var bt = 0u; bt < batches; bt = bt + 1u) {
        let first = a + bt * BATCH;
        let idx = first + li;
        if (idx < b) {
            let g = isect_prims[idx];
            let bx = stage(li, proj_xy[g], proj_conic[g], proj_rgb[g], origin);
            if (KEEP_BOXES) { isect_box[idx] = bx; }
        }
        workgroupBarrier();
        blend_batch(p, col, row, min(b - first, BATCH), pos0 + bt * BATCH, stop);
        if (all_done(li)) {
            unboxed(first + BATCH, b, li);
            break;
        }
    }
}

// A chunk's pixel into slab `slot` (t negated where stopped, as composite.wgsl write_slab).
fn write_slab(p: ptr<function, Quad>, slot: u32, col: u32, row: u32) {
    let q = *p;
    chunk_slabs[slot * TILE_PIXELS + row * TILE + col] = vec4<f32>(q.r, q.g, q.b, select(q.T, -q.T, q.done));
}

fn read_slab(slot: u32, col: u32, row: u32, p0: Quad) -> Quad {
    var p = p0;
    let v = chunk_slabs[slot * TILE_PIXELS + row * TILE + col];
    p.r = v.x;
    p.g = v.y;
    p.b = v.z;
    let stopped = v.w < 0.0;
    p.T = select(v.w, -v.w, stopped);
    p.done = stopped;
    return p;
}

// The pixel (C + T * background, T) into the image (tile-local column `col`, row `row` of tile
// (tx, ty)), if it lies in the viewport.
fn write_image(p: ptr<function, Quad>, tx: u32, ty: u32, col: u32, row: u32) {
    let x = tx * TILE + col;
    let y = ty * TILE + row;
    if (x < bin.width && y < bin.height) {
        let q = *p;
        image[image_index(x, y)] =
            vec4<f32>(vec3<f32>(q.r, q.g, q.b) + unfused_v3(q.T * bin.background.xyz), q.T);
    }
}

// KEEP_BOXES frames: the list position of the record the pixel stopped at (NEVER: none, or a list
// longer than a chunk), indexed as the image.
fn write_stops(stop: ptr<function, u32>, tx: u32, ty: u32, col: u32, row: u32) {
    let x = tx * TILE + col;
    let y = ty * TILE + row;
    if (KEEP_BOXES && x < bin.width && y < bin.height) {
        stop_pos[image_index(x, y)] = *stop;
    }
}

fn no_stops() -> u32 {
    return NEVER;
}

// A later chunk's start: the pixel's position and whether it has ended, C = 0, T = 1.
fn restart(acc: ptr<function, Quad>) -> Quad {
    return Quad((*acc).x, (*acc).y, 0.0, 0.0, 0.0, 1.0, (*acc).done);
}

// A pixel that ended in `first` (its tile's chunk 0, read back from the slab) stays ended.
fn keep_ended(p: ptr<function, Quad>, first: Quad) {
    (*p).done = (*p).done | first.done;
}

fn merge_pixels(acc: ptr<function, Quad>, c: ptr<function, Quad>, first: bool) {
    *acc = merge_quad(*acc, *c, first);
}
