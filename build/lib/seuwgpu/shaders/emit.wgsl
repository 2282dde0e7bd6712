// Emit one (tile id, primitive) pair per touched tile, in depth order, at the scanned offsets.

@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> rects: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> sorted_prims: array<u32>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> isect_tiles: array<u32>;
@group(0) @binding(5) var<storage, read_write> isect_prims: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = gid.x + gid.y * nwg.x * 256u;
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
