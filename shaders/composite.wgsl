// #import composite_lanes
// #import composite_frame

// Full-frame compositing in the "lanes" shape (render/composite.py Compositing), and the merge of
// long tiles that both shapes use: one workgroup per chunk of a TILE x TILE tile's list
// (CHUNK_PAIRS pairs: most tiles are one chunk; docs/renderer.md "Long tile lists").
// - main: chunk 0 of every tile of a full frame (the image of a one-chunk tile); chunks: the later
//   chunks of long tiles, in parallel, into slabs (both composite_frame.wgsl's, over
//   composite_lanes.wgsl's pixels);
// - merge: those slabs into the image, front to back (blend.wgsl merge_quad, the one merge of
//   chunks), for either shape: a slab holds the same bits whichever shape wrote it.
// The entry points share the blending code, so their arithmetic is identical bit for bit.

// The image pixels of long tiles: their chunks' slabs merged front to back.
@compute @workgroup_size(TILE, ROWS)
fn merge(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_id) lid: vec3<u32>) {
    opaque_zero = bitcast<u32>(bin.background.w);  // blend.wgsl unfused
    let count = work_counts[2];
    let row0 = lid.y * SPAN;
    for (var e = wg.x; e < count; e = e + nwg.x) {
        let item = merge_list[e];
        let txy = enter_tile(item.x);
        let tx = txy.x;
        let ty = txy.y;
        var acc = tile_pixels(tx, ty, lid.x, row0);
        let range = ranges[item.x];
        let n_chunks = (range.y - range.x + CHUNK_PAIRS - 1u) / CHUNK_PAIRS;
        for (var c = 0u; c < n_chunks; c = c + 1u) {
            var ch = read_slab(item.y + c, lid.x, row0, acc);
            merge_pixels(&acc, &ch, c == 0u);
            if (all_pixels_done(&acc)) {
                break;
            }
        }
        write_image(&acc, tx, ty, lid.x, row0);
    }
}
