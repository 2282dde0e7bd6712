// Full-frame compositing in the shape GPUs fill (render/composite.py, Compositing(shape="wide")):
// one pixel per invocation and one TILE x TILE workgroup (256 invocations) a tile, as GPU
// rasterizers do (gsplat, the INRIA rasterizer). composite.wgsl's main and chunks give each of 32
// invocations 8 pixels, the right shape for CPU Vulkan, but one warp a tile on a GPU: 1,024 tiles
// fill about an eighth of an H200's thread slots (docs/renderer.md). The tiles, chunks, slabs and
// work lists are blend.wgsl's, shared with composite.wgsl, whose `merge` blends long tiles' slabs.
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

// Pixel (x, y) (full-frame coordinates), done from the start outside the viewport (w x h from
// `first`, its first pixel).
fn make_pixel(x: u32, y: u32, first: vec2<u32>, size: vec2<u32>) -> Quad {
    let inside = x - first.x < size.x && y - first.y < size.y;
    return Quad(f32(x) + 0.5, f32(y) + 0.5, 0.0, 0.0, 0.0, 1.0, !inside);
}

fn tile_pixel(tx: u32, ty: u32, col: u32, row: u32) -> Quad {
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
fn write_slab(p: Quad, slot: u32, col: u32, row: u32) {
    chunk_slabs[slot * TILE_PIXELS + row * TILE + col] = vec4<f32>(p.r, p.g, p.b, select(p.T, -p.T, p.done));
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
fn write_pixel(p: Quad, tx: u32, ty: u32, col: u32, row: u32) {
    let x = tx * TILE + col;
    let y = ty * TILE + row;
    if (x < bin.width && y < bin.height) {
        image[(bin.stats_index * bin.height + y) * bin.width + x] =
            vec4<f32>(vec3<f32>(p.r, p.g, p.b) + p.T * bin.background.xyz, p.T);
    }
}

// KEEP_BOXES frames: the list position of the record the pixel stopped at (NEVER: none, or a list
// longer than a chunk), indexed as the image.
fn write_stop(stop: u32, tx: u32, ty: u32, col: u32, row: u32) {
    let x = tx * TILE + col;
    let y = ty * TILE + row;
    if (KEEP_BOXES && x < bin.width && y < bin.height) {
        stop_pos[(bin.stats_index * bin.height + y) * bin.width + x] = stop;
    }
}

// Chunk 0 of every tile; a tile of one chunk writes its pixels, a longer one its slab, and lists
// its later chunks (for `chunks`) and its merge (for composite.wgsl's `merge`).
@compute @workgroup_size(TILE, TILE)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let tile = wg.y * bin.tiles_x + wg.x;
    var p = tile_pixel(wg.x, wg.y, lid.x, lid.y);
    let range = ranges[tile];
    let n = range.y - range.x;
    let origin = vec2<f32>(tile_first(wg.x, wg.y));
    var stop = NEVER;
    composite_range(&p, range.x, range.x + min(n, CHUNK_PAIRS), origin, lid.x, lid.y, li, 0u, &stop);
    if (n <= CHUNK_PAIRS) {
        write_pixel(p, wg.x, wg.y, lid.x, lid.y);
        write_stop(stop, wg.x, wg.y, lid.x, lid.y);
        return;
    }
    write_stop(NEVER, wg.x, wg.y, lid.x, lid.y);  // long lists: unknown
    let n_chunks = (n + CHUNK_PAIRS - 1u) / CHUNK_PAIRS;
    let w = list_long_tile(tile, n_chunks, li);
    if (w.z == 0u) {
        // no room for its slabs: its chunks run here in sequence
        var acc = p;
        for (var c = 1u; c < n_chunks; c = c + 1u) {
            p = Quad(acc.x, acc.y, 0.0, 0.0, 0.0, 1.0, acc.done);
            let a = range.x + c * CHUNK_PAIRS;
            composite_range(&p, a, min(range.y, a + CHUNK_PAIRS), origin, lid.x, lid.y, li, c * CHUNK_PAIRS, &stop);
            acc = merge_quad(acc, p, false);
        }
        write_pixel(acc, wg.x, wg.y, lid.x, lid.y);
        return;
    }
    write_slab(p, w.x, lid.x, lid.y);
}

// The later chunks of long tiles, from main's list, each into its slab.
@compute @workgroup_size(TILE, TILE)
fn chunks(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let count = min(work_counts[1], arrayLength(&extra_list));
    for (var e = wg.x; e < count; e = e + nwg.x) {
        let item = extra_list[e];
        if (item.x == VOID) {
            continue;
        }
        let tx = item.x % bin.tiles_x;
        let ty = item.x / bin.tiles_x;
        var p = tile_pixel(tx, ty, lid.x, lid.y);
        // a pixel that stopped in chunk 0 has ended: the merge ignores its later chunks
        p.done = p.done | read_slab(item.z - item.y, lid.x, lid.y, p).done;
        let range = ranges[item.x];
        let a = range.x + item.y * CHUNK_PAIRS;
        var stop: u32;  // not kept for later chunks
        composite_range(&p, a, min(range.y, a + CHUNK_PAIRS), vec2<f32>(tile_first(tx, ty)), lid.x, lid.y, li, 0u, &stop);
        write_slab(p, item.z, lid.x, lid.y);
    }
}
