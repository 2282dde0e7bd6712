// Tile binning (render/bin.py), per view: intersection counts in depth order, emission of
// (tile, primitive) pairs at the scanned offsets, and per-tile ranges of the tile-sorted list.
// Between them the host scans the counts (gpu/sort.py PrefixSum) and sorts the pairs by tile
// (render/sort.py). Rectangles are packed (x0 | y0 << 16, x1 | y1 << 16) in tiles, exclusive max.

@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> rects: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> sorted_prims: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
@group(0) @binding(5) var<storage, read_write> isect_tiles: array<u32>;
@group(0) @binding(6) var<storage, read_write> isect_prims: array<u32>;
@group(0) @binding(7) var<storage, read> stats: array<u32>;
@group(0) @binding(8) var<storage, read_write> ranges: array<vec2<u32>>;

fn rect_count(r: vec2<u32>) -> u32 {
    let x0 = r.x & 0xffffu;
    let y0 = r.x >> 16u;
    let x1 = r.y & 0xffffu;
    let y1 = r.y >> 16u;
    return (x1 - x0) * (y1 - y0);
}

// counts[s] = tiles touched by the s-th primitive in depth order (culled ones have empty rects).
@compute @workgroup_size(WG)
fn count_tiles(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= bin.n_total) {
        return;
    }
    counts[s] = rect_count(rects[sorted_prims[s]]);
}

// One (tile id, primitive) pair per touched tile, in depth order, at the scanned offsets; pairs
// past the capacity are dropped (the host sees the total, grows the buffers and re-runs).
@compute @workgroup_size(WG)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= bin.n_total) {
        return;
    }
    let g = sorted_prims[s];
    let r = rects[g];
    let x0 = r.x & 0xffffu;
    let y0 = r.x >> 16u;
    let x1 = r.y & 0xffffu;
    let y1 = r.y >> 16u;
    var o = offsets[s];
    for (var ty = y0; ty < y1; ty = ty + 1u) {
        for (var tx = x0; tx < x1; tx = tx + 1u) {
            if (o < bin.capacity) {
                isect_tiles[o] = ty * bin.tiles_x + tx;
                isect_prims[o] = g;
            }
            o = o + 1u;
        }
    }
}

// first index i in [0, n) with isect_tiles[i] >= t
fn lower_bound(t: u32, n: u32) -> u32 {
    var lo = 0u;
    var hi = n;
    while (lo < hi) {
        let mid = (lo + hi) >> 1u;
        if (isect_tiles[mid] < t) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// Per-tile [start, end) in the tile-sorted list, by binary search (no clearing, no atomics, no
// dependence on the dynamic count's dispatch size).
@compute @workgroup_size(WG)
fn tile_ranges(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = linear_id(gid, nwg);
    if (t >= bin.n_tiles) {
        return;
    }
    let n = min(stats[bin.stats_index], bin.capacity);
    ranges[t] = vec2<u32>(lower_bound(t, n), lower_bound(t + 1u, n));
}
