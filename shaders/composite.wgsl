// Front-to-back compositing: one 16x16 workgroup per tile, intersections staged through
// workgroup memory in batches of 256. Rules (skips, NaN-propagating min, early stop) are in
// docs/renderer.md. Output pixel = (C + T * background, T).

@group(0) @binding(0) var<uniform> bin: Binning;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> isect_prims: array<u32>;
@group(0) @binding(3) var<storage, read> proj_xy: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> proj_conic: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> proj_rgb: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> image: array<vec4<f32>>;

var<workgroup> s_xy: array<vec2<f32>, 256>;
var<workgroup> s_conic: array<vec4<f32>, 256>;
var<workgroup> s_rgb: array<vec4<f32>, 256>;
var<workgroup> s_done: atomic<u32>;
var<workgroup> s_all_done: u32;

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let tile = wg.y * bin.tiles_x + wg.x;
    let px = wg.x * 16u + lid.x;
    let py = wg.y * 16u + lid.y;
    let inside = px < bin.width && py < bin.height;
    if (li == 0u) {
        atomicStore(&s_done, 0u);
        s_all_done = 0u;
    }
    workgroupBarrier();
    var done = !inside;
    if (done) {
        atomicAdd(&s_done, 1u);
    }
    let pix = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    var T = 1.0;
    var C = vec3<f32>(0.0);
    let range = ranges[tile];
    let n = range.y - range.x;
    let batches = (n + 255u) / 256u;
    for (var b = 0u; b < batches; b = b + 1u) {
        let idx = range.x + b * 256u + li;
        if (idx < range.y) {
            let g = isect_prims[idx];
            s_xy[li] = proj_xy[g];
            s_conic[li] = proj_conic[g];
            s_rgb[li] = proj_rgb[g];
        }
        workgroupBarrier();
        let m = min(256u, n - b * 256u);
        if (!done) {
            for (var k = 0u; k < m; k = k + 1u) {
                let co = s_conic[k];
                let d = s_xy[k] - pix;
                let sigma = 0.5 * (co.x * d.x * d.x + co.z * d.y * d.y) + co.y * d.x * d.y;
                // NaN never takes a skip or stop branch: it must reach the pixel (bit tests, since
                // compilers may assume finite math).
                if (!is_nan_f32(sigma) && sigma < 0.0) {
                    continue;
                }
                let a = co.w * exp_ieee(-sigma);
                var alpha = a;
                if (!is_nan_f32(a)) {
                    alpha = min(0.99, a);
                }
                if (!is_nan_f32(alpha) && alpha < 1.0 / 255.0) {
                    continue;
                }
                let next_t = T * (1.0 - alpha);
                if (!is_nan_f32(next_t) && next_t <= 1e-4) {
                    done = true;
                    atomicAdd(&s_done, 1u);
                    break;
                }
                C = C + s_rgb[k].xyz * (alpha * T);
                T = next_t;
            }
        }
        workgroupBarrier();
        if (li == 0u) {
            s_all_done = atomicLoad(&s_done);
        }
        if (workgroupUniformLoad(&s_all_done) == 256u) {
            break;
        }
    }
    if (inside) {
        image[(bin.stats_index * bin.height + py) * bin.width + px] = vec4<f32>(C + T * bin.background.xyz, T);
    }
}
