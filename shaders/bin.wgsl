// #import common

// Tile binning (render/bin.py), per list of `bin.views` frames (1, or the K views of a batched
// renderer: render/renderer.py): each record's intersection count, the counts gathered into depth
// order, scanned there (gpu/sort.py PrefixSum) and the offsets scattered back to the records, the
// emission of (tile, primitive) pairs at those offsets, and per-tile ranges of the list once the
// host sorted it by tile (render/sort.py). Counting and emission walk the records in their own
// order and read their screen data sequentially; walked in depth order they gathered 32 bytes a
// record from three arrays at random (docs/benchmarks.md: at 1M primitives counting, scanning
// and emission took 167 GPU ms a view that way, 68 this way). Only the 4-byte counts and
// offsets move between the two orders. Rectangles are packed (x0 | y0 << 16, x1 | y1 << 16) in
// tiles, exclusive max.
//
// Exact binning (docs/renderer.md): a primitive is paired with the tiles of its rectangle that its
// footprint may reach (common.wgsl reach / row_tiles: per tile row, the columns the ellipse
// crosses), not with the whole rectangle: the tiles it provably cannot reach would only be staged
// and skipped at every pixel. Both passes compute the same rows, so counts and pairs agree. EXACT_BIN = false
// pairs the whole rectangle (the images are the same bit for bit; tests compare the two).
//
// Batched views: the screen records of view v are records v * n_total .. (v + 1) * n_total - 1
// (depth_vals, depth-sorted, holds those indices, all views mixed in one depth order), and a pair's tile id is
// v * n_tiles + its tile in view v, so the stable tile sort leaves each tile of each view its own
// list, front to back with ties by primitive index, as one view's list alone would be.
override EXACT_BIN: bool = true;

@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> proj_rect: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> depth_vals: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;     // depth order: counts, scanned in place
@group(0) @binding(4) var<storage, read_write> by_record: array<u32>;  // per record: its count, then its offset
@group(0) @binding(5) var<storage, read_write> isect_tiles: array<u32>;
@group(0) @binding(6) var<storage, read_write> isect_prims: array<u32>;
@group(0) @binding(7) var<storage, read_write> stats: array<u32>;
@group(0) @binding(8) var<storage, read_write> ranges: array<vec2<u32>>;
@group(0) @binding(9) var<storage, read> proj_xy: array<vec2<f32>>;
@group(0) @binding(10) var<storage, read> proj_conic: array<vec4<f32>>;  // conic, opacity

// A primitive's rectangle (tiles, exclusive max) and its reach (REACH_ALL without exact binning).
struct Footprint {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    r: Reach,
};

fn footprint(g: u32) -> Footprint {
    let q = proj_rect[g];
    var f = Footprint(q.x & 0xffffu, q.x >> 16u, q.y & 0xffffu, q.y >> 16u,
        Reach(REACH_ALL, vec2<f32>(0.0), vec4<f32>(0.0), 0.0, 0.0, 0.0, 0.0));
    if (f.x1 <= f.x0 || f.y1 <= f.y0) {
        f.y1 = f.y0;  // culled: no rows
    } else if (EXACT_BIN) {
        f.r = reach(proj_xy[g], proj_conic[g]);
    }
    return f;
}

// Columns [c0, c1) of tile row ty that the primitive is paired with.
fn row_of(f: Footprint, ty: u32) -> vec2<u32> {
    let first = vec2<f32>(f32(bin.origin & 0xffffu), f32(bin.origin >> 16u));
    return row_tiles(f.r, first.y + f32(ty * TILE), first.x, f.x0, f.x1);
}

// by_record[g] = tiles paired with record g (culled ones have an empty proj_rect).
@compute @workgroup_size(WG)
fn count_tiles(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let g = linear_id(gid, nwg);
    if (g >= bin.views * bin.n_total) {
        return;
    }
    let f = footprint(g);
    var c = 0u;
    if (f.r.kind == REACH_ALL) {
        c = (f.x1 - f.x0) * (f.y1 - f.y0);
    } else {
        for (var ty = f.y0; ty < f.y1; ty = ty + 1u) {
            let cols = row_of(f, ty);
            c = c + (cols.y - cols.x);
        }
    }
    by_record[g] = c;
}

// counts[s] = the count of the s-th record in depth order (depth_vals, depth-sorted, is a permutation of the
// records), for the scan.
@compute @workgroup_size(WG)
fn gather_counts(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= bin.views * bin.n_total) {
        return;
    }
    counts[s] = by_record[depth_vals[s]];
}

// by_record[g] = record g's offset, from the scanned depth-ordered counts.
@compute @workgroup_size(WG)
fn scatter_offsets(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= bin.views * bin.n_total) {
        return;
    }
    by_record[depth_vals[s]] = counts[s];
}

// One (tile id, primitive) pair per paired tile of record g, row-major, at its scanned offset:
// the list is in depth order whatever order the records are walked in. Pairs past the capacity
// are dropped (the host sees the total, grows the buffers and re-runs).
@compute @workgroup_size(WG)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let g = linear_id(gid, nwg);
    if (g >= bin.views * bin.n_total) {
        return;
    }
    let f = footprint(g);
    let first_tile = (g / bin.n_total) * bin.n_tiles;  // its view's first tile id (batched views)
    var o = by_record[g];
    for (var ty = f.y0; ty < f.y1; ty = ty + 1u) {
        let cols = row_of(f, ty);
        for (var tx = cols.x; tx < cols.y; tx = tx + 1u) {
            if (o < bin.capacity) {
                isect_tiles[o] = first_tile + ty * bin.tiles_x + tx;
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
    if (t >= bin.views * bin.n_tiles) {
        return;
    }
    let n = min(stats[bin.stats_index], bin.capacity);
    let r = vec2<u32>(lower_bound(t, n), lower_bound(t + 1u, n));
    ranges[t] = r;
    // batched views: the last tile of each view also writes the view's total (its list is the
    // pairs from its first tile's start to its last tile's end)
    if (bin.views > 1u && (t + 1u) % bin.n_tiles == 0u) {
        let v = t / bin.n_tiles;
        stats[bin.frame + v] = r.y - lower_bound(v * bin.n_tiles, n);
    }
}
