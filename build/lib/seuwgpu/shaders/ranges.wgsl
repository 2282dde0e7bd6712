// Per-tile [start, end) in the tile-sorted intersection list, by binary search (no clearing, no
// atomics, no dependence on the dynamic count's dispatch size).

@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> isect_tiles: array<u32>;
@group(0) @binding(2) var<storage, read> stats: array<u32>;
@group(0) @binding(3) var<storage, read_write> ranges: array<vec2<u32>>;

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

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = gid.x + gid.y * nwg.x * 256u;
    if (t >= bin.n_tiles) {
        return;
    }
    let n = min(stats[bin.stats_index], bin.capacity);
    ranges[t] = vec2<u32>(lower_bound(t, n), lower_bound(t + 1u, n));
}
