// #import blend

// The full-frame entry points `main` and `chunks`, written once for both compositors: the two
// compositor shapes (composite.wgsl, "lanes", and composite_wide.wgsl, "wide") import this file,
// and a compositor that imports it MUST supply (with blend.wgsl's lane types PF / PB / PU):
//   types      P, one invocation's pixels, whatever tile_pixels returns (the lanes shape's
//              Pixels: a column of SPAN = 8 in vec4 lanes; the wide one's blend.wgsl Quad of
//              scalar lanes, SPAN = 1), and Stops, their stop positions
//   consts     SPAN (pixel rows an invocation holds), ROWS = TILE / SPAN (invocation rows a tile)
//   functions  tile_pixels(tx, ty, col, row0) -> P
//              restart(acc) -> P        a chunk's start: positions and ended lanes, C = 0, T = 1
//              keep_ended(p, first)
//              composite_range(p, a, b, origin, col, row0, li, pos0, stops)
//              merge_pixels(acc, c, first)
//              write_image(p, tx, ty, col, row0)
//              no_stops() -> Stops
//              write_stops(stops, tx, ty, col, row0)   (KEEP_BOXES frames only)
//              write_slab(p, slot, col, row0)
//              read_slab(slot, col, row0, p0) -> P
// composite.wgsl's `merge` then blends the slabs of long tiles for either shape.

// Chunk 0 of every tile; a tile of one chunk writes its pixels, a longer one its slab, and lists
// its later chunks (for `chunks`) and its merge (for composite.wgsl's `merge`).
@compute @workgroup_size(TILE, ROWS)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    frame_view = wg.z;  // one grid layer per frame of a batched list
    opaque_zero = bitcast<u32>(bin.background.w);  // blend.wgsl unfused
    let tile = wg.z * bin.n_tiles + wg.y * bin.tiles_x + wg.x;
    let row0 = lid.y * SPAN;
    var p = tile_pixels(wg.x, wg.y, lid.x, row0);
    let range = ranges[tile];
    let n = range.y - range.x;
    let origin = vec2<f32>(tile_first(wg.x, wg.y));
    var stops = no_stops();
    composite_range(&p, range.x, range.x + min(n, CHUNK_PAIRS), origin, lid.x, row0, li, 0u, &stops);
    if (n <= CHUNK_PAIRS) {
        write_image(&p, wg.x, wg.y, lid.x, row0);
        write_stops(&stops, wg.x, wg.y, lid.x, row0);
        return;
    }
    stops = no_stops();  // long lists: unknown
    write_stops(&stops, wg.x, wg.y, lid.x, row0);
    let n_chunks = (n + CHUNK_PAIRS - 1u) / CHUNK_PAIRS;
    let w = list_long_tile(tile, n_chunks, li);
    if (w.z == 0u) {
        // no room for its slabs: its chunks run here in sequence
        var acc = p;
        for (var c = 1u; c < n_chunks; c = c + 1u) {
            p = restart(&acc);
            let a = range.x + c * CHUNK_PAIRS;
            composite_range(&p, a, min(range.y, a + CHUNK_PAIRS), origin, lid.x, row0, li, c * CHUNK_PAIRS, &stops);
            merge_pixels(&acc, &p, false);
        }
        write_image(&acc, wg.x, wg.y, lid.x, row0);
        return;
    }
    write_slab(&p, w.x, lid.x, row0);
}

// The later chunks of long tiles, from main's list, each into its slab.
@compute @workgroup_size(TILE, ROWS)
fn chunks(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    opaque_zero = bitcast<u32>(bin.background.w);
    let count = min(work_counts[1], arrayLength(&extra_list));
    let row0 = lid.y * SPAN;
    for (var e = wg.x; e < count; e = e + nwg.x) {
        let item = extra_list[e];
        if (item.x == VOID) {
            continue;
        }
        let txy = enter_tile(item.x);
        let tx = txy.x;
        let ty = txy.y;
        var p = tile_pixels(tx, ty, lid.x, row0);
        // pixels that stopped in chunk 0 have ended: the merge ignores their later chunks, so they
        // are not composited (a dense opaque region costs one chunk, not all of them)
        keep_ended(&p, read_slab(item.z - item.y, lid.x, row0, p));
        let range = ranges[item.x];
        let a = range.x + item.y * CHUNK_PAIRS;
        var stops: Stops;  // not kept for later chunks
        composite_range(&p, a, min(range.y, a + CHUNK_PAIRS), vec2<f32>(tile_first(tx, ty)), lid.x, row0, li, 0u, &stops);
        write_slab(&p, item.z, lid.x, row0);
    }
}
