// Tile binning: intersection counts in depth order, emission of (tile, primitive) pairs at the
// scanned offsets, and per-tile ranges of the tile-sorted list.

@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> rects: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> sorted_prims: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;

fn rect_count(r: vec2<u32>) -> u32 {
    let x0 = r.x & 0xffffu;
    let y0 = r.x >> 16u;
    let x1 = r.y & 0xffffu;
    let y1 = r.y >> 16u;
    return (x1 - x0) * (y1 - y0);
}

// counts[s] = tiles touched by the s-th primitive in depth order (culled ones have empty rects).
@compute @workgroup_size(256)
fn count_tiles(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = gid.x + gid.y * nwg.x * 256u;
    if (s >= bin.n_total) {
        return;
    }
    counts[s] = rect_count(rects[sorted_prims[s]]);
}
