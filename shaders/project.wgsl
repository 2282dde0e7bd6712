// #import codes

// Projection (render/project.py): decode the stored primitive, EWA-project it into one view,
// evaluate SH colour, and compute its tile rectangle. One thread per primitive of one model chunk.
// Rules (culling, unbounded footprints, saturating rectangles) are in docs/renderer.md.
//
// One pipeline per (stored precision, SH degree, guard mask): the overrides below turn the
// per-component format and guard branches into straight-line code (render/project.py picks the
// pipeline from the slot's `fmt`, `sh_degree`, `guard_lo` and `guard_hi`).
override FMT: u32 = 0u;           // FMT_FP32, FMT_FP16 or FMT_BF16
override SH_DEGREE: u32 = 3u;
override GUARD_LO: u32 = 0u;      // in-pipeline guard: components 0..31 to clamp
override GUARD_HI: u32 = 0u;      // components 32..63
// The check inside the frame (issue 47; faults/check.py FrameCheck): 0 = off (the pipeline is
// today's, bit for bit); otherwise the parity bits of each value FRAME_COVER covers, over every
// stored component, in FRAME_WAYS ways (bit b of value c in way (b + FRAME_DIAGONAL c) % FRAME_WAYS:
// codes.wgsl parity_fold), against the stored code, for every primitive the view would draw: one
// that fails is dropped from this frame (culled), counted and, with FRAME_FLAGS, flagged for
// repair. A primitive culled anyway is not checked (it draws nothing either way). Each value is
// folded as the projection reads it (`stored`), not read a second time. FRAME_PER_WORD
// (fp16/bf16 only): the code is a stored word's, both primitives of the pair (codes.wgsl
// coded_pattern, code_index), so a failing word drops both from the frame.
override FRAME_CHECK: u32 = 0u;
override FRAME_COVER: u32 = 0u;
override FRAME_WAYS: u32 = 4u;
override FRAME_DIAGONAL: u32 = 0u;
override FRAME_FLAGS: u32 = 1u;
override FRAME_PER_WORD: u32 = 0u;

struct View {
    viewmat: mat4x4<f32>,     // world-to-camera, column-major (as WGSL stores it)
    campos: vec4<f32>,        // camera centre in world space (w unused)
    intr: vec4<f32>,          // fx, fy, cx, cy
    background: vec4<f32>,
    width: u32,               // full camera image (Jacobian clamp)
    height: u32,
    tiles_x: u32,             // tiles of the viewport (the whole frame unless rendering a region)
    tiles_y: u32,
    n_total: u32,             // primitives in the model
    chunk_base: u32,          // first primitive of this chunk
    chunk_count: u32,         // primitives in this chunk
    plane_words: u32,         // u32 words per component plane
    sh_degree: u32,           // = SH_DEGREE of the pipeline that reads this slot
    fmt: u32,                 // = FMT of that pipeline
    view_index: u32,
    guard_lo: u32,            // = GUARD_LO of that pipeline
    guard_hi: u32,            // = GUARD_HI
    tile_x0: f32,             // viewport origin in tiles (sort-first regions); 0 for a full frame
    tile_y0: f32,
    _p2: u32,
};

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> model: array<u32>;
@group(0) @binding(2) var<storage, read_write> proj_xy: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> proj_conic: array<vec4<f32>>;   // conic.xyz, opacity
@group(0) @binding(4) var<storage, read_write> proj_rgb: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> proj_rect: array<vec2<u32>>;    // (x0 | y0 << 16, x1 | y1 << 16)
@group(0) @binding(6) var<storage, read_write> depth_keys: array<u32>;
@group(0) @binding(7) var<storage, read_write> depth_vals: array<u32>;
// In-pipeline support guard (memory untouched): the box, and clamp counts per field (view 0).
@group(0) @binding(8) var<storage, read> box: array<Bound>;
@group(0) @binding(9) var<storage, read_write> guard_counts: array<atomic<u32>>;
// The check inside the frame: 4-bit codes per primitive (side.pack_side), and its output as
// codes.wgsl's OUT_* words lay it out (detected, detected_copy, 2 words, then a flag bit per primitive).
@group(0) @binding(10) var<storage, read> frame_side: array<u32>;
@group(0) @binding(11) var<storage, read_write> frame_out: array<atomic<u32>>;

// Renderer profile (docs/renderer.md, "Profiles"): PROFILE_STRICT (default) or PROFILE_GSPLAT.
// A pipeline override, so each profile compiles to its own specialised pipeline.
override PROFILE: u32 = PROFILE_STRICT;

const SH_C0: f32 = 0.28209479177387814;
const SH_C1: f32 = 0.4886025119029199;

// the frame check's fold of the stored words this invocation has read (stored): the projection
// reads each value of a primitive it draws exactly once, so the check costs a fold per value, not
// a second read of the primitive
var<private> frame_fold: u32 = 0u;

fn stored(j: u32, c: u32) -> f32 {
    let w = model[stored_word_index(c, j, view.plane_words, FMT)];
    if (FRAME_CHECK != 0u) {
        frame_fold = parity_fold(frame_fold, coded_pattern(w, j, FMT, FRAME_PER_WORD) & FRAME_COVER, c, FRAME_WAYS, FRAME_DIAGONAL);
    }
    if (FMT == FMT_FP32) {
        return bitcast<f32>(w);
    }
    return decode_value(w, (j & 1u) == 1u, FMT);
}

fn guard_on(c: u32) -> bool {
    if (c < 32u) {
        return ((GUARD_LO >> c) & 1u) == 1u;
    }
    return ((GUARD_HI >> (c - 32u)) & 1u) == 1u;
}

// Each component is read exactly once per primitive and view, so clamps are counted once (view 0).
fn comp(j: u32, c: u32) -> f32 {
    let v = stored(j, c);
    if (!guard_on(c)) {
        return v;
    }
    let b = box[c];
    let side = guard_side(v, b.lo, b.hi);
    if (side == 0u) {
        return v;
    }
    if (view.view_index == 0u) {
        atomicAdd(&guard_counts[field_of(c)], 1u);
    }
    return select(b.hi, b.lo, side == 1u);
}

// Colour = SH + 0.5, then max(., 0) per channel, except that NaN stays NaN.
fn activate_colour(v: f32) -> f32 {
    if (is_nan_f32(v)) {
        return v;
    }
    return max(v, 0.0);
}

// SH coefficient k (1..15) of primitive j as rgb.
fn shc(j: u32, k: u32) -> vec3<f32> {
    let base = 11u + 3u * k;
    return vec3<f32>(comp(j, base), comp(j, base + 1u), comp(j, base + 2u));
}

// INRIA/gsplat SH evaluation, accumulated in coefficient order (written out: private arrays with
// dynamic indices are slow on CPU Vulkan).
fn sh_colour(j: u32, dir: vec3<f32>) -> vec3<f32> {
    var c = SH_C0 * shc(j, 0u);
    let deg = SH_DEGREE;
    if (deg > 0u) {
        let x = dir.x;
        let y = dir.y;
        let z = dir.z;
        c = c + (-SH_C1 * y) * shc(j, 1u);
        c = c + (SH_C1 * z) * shc(j, 2u);
        c = c + (-SH_C1 * x) * shc(j, 3u);
        if (deg > 1u) {
            let xx = x * x; let yy = y * y; let zz = z * z;
            let xy = x * y; let yz = y * z; let xz = x * z;
            c = c + (1.0925484305920792 * xy) * shc(j, 4u);
            c = c + (-1.0925484305920792 * yz) * shc(j, 5u);
            c = c + (0.31539156525252005 * (2.0 * zz - xx - yy)) * shc(j, 6u);
            c = c + (-1.0925484305920792 * xz) * shc(j, 7u);
            c = c + (0.5462742152960396 * (xx - yy)) * shc(j, 8u);
            if (deg > 2u) {
                c = c + (-0.5900435899266435 * y * (3.0 * xx - yy)) * shc(j, 9u);
                c = c + (2.890611442640554 * xy * z) * shc(j, 10u);
                c = c + (-0.4570457994644658 * y * (4.0 * zz - xx - yy)) * shc(j, 11u);
                c = c + (0.3731763325901154 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)) * shc(j, 12u);
                c = c + (-0.4570457994644658 * x * (4.0 * zz - xx - yy)) * shc(j, 13u);
                c = c + (1.445305721320277 * z * (xx - yy)) * shc(j, 14u);
                c = c + (-0.5900435899266435 * x * (xx - 3.0 * yy)) * shc(j, 15u);
            }
        }
    }
    c = c + vec3<f32>(0.5);
    return vec3<f32>(activate_colour(c.x), activate_colour(c.y), activate_colour(c.z));
}

// Scales exp(log_scales) of primitive j.
fn scales(j: u32) -> vec3<f32> {
    return vec3<f32>(exp_ieee(comp(j, 3u)), exp_ieee(comp(j, 4u)), exp_ieee(comp(j, 5u)));
}

// Rotation of the normalised quaternion (w, x, y, z) of primitive j, gsplat's quat_to_rotmat.
fn rotation(j: u32) -> mat3x3<f32> {
    let q0 = vec4<f32>(comp(j, 6u), comp(j, 7u), comp(j, 8u), comp(j, 9u));
    let q = q0 * rsqrt_ieee(dot(q0, q0));
    let w = q.x; let x = q.y; let y = q.z; let z = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)));
}

// EWA Jacobian (2x3; WGSL mat3x2 has 3 columns of vec2) with gsplat's clamp 30% beyond the
// image edge; `glm`: glm's min/max, which drop a NaN second operand (gsplat profile).
fn jacobian(p: vec3<f32>, rz: f32, glm: bool) -> mat3x2<f32> {
    let fx = view.intr.x;
    let fy = view.intr.y;
    let cx = view.intr.z;
    let cy = view.intr.w;
    let width = f32(view.width);
    let height = f32(view.height);
    let tan_fovx = 0.5 * width / fx;
    let tan_fovy = 0.5 * height / fy;
    let lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx;
    let lim_x_neg = cx / fx + 0.3 * tan_fovx;
    let lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy;
    let lim_y_neg = cy / fy + 0.3 * tan_fovy;
    var tx = p.z * min(lim_x_pos, max(-lim_x_neg, p.x * rz));
    var ty = p.z * min(lim_y_pos, max(-lim_y_neg, p.y * rz));
    if (glm) {
        tx = p.z * glm_min(lim_x_pos, glm_max(-lim_x_neg, p.x * rz));
        ty = p.z * glm_min(lim_y_pos, glm_max(-lim_y_neg, p.y * rz));
    }
    return mat3x2<f32>(
        vec2<f32>(fx * rz, 0.0),
        vec2<f32>(0.0, fy * rz),
        vec2<f32>(-fx * tx * rz * rz, -fy * ty * rz * rz));
}

fn cull(g: u32) {
    depth_keys[g] = 0xffffffffu;
    depth_vals[g] = g;
    proj_rect[g] = vec2<u32>(0u, 0u);
}

// the frame's check of primitive j (global index g), once every value is read: true when the
// fold of its values (frame_fold) fails its code word
fn frame_check_fails(g: u32) -> bool {
    let p = g % view.n_total;  // the primitive (a batched renderer writes view v's records at v n + p)
    let q = code_index(p, FRAME_PER_WORD);
    return parity_code(frame_fold, FRAME_WAYS) != code_of(frame_side[code_word_index(q, FRAME_WAYS)], q, FRAME_WAYS);
}

fn pack_rect(x0: f32, y0: f32, x1: f32, y1: f32) -> vec2<u32> {
    return vec2<u32>(u32(x0) | (u32(y0) << 16u), u32(x1) | (u32(y1) << 16u));
}

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= view.chunk_count) {
        return;
    }
    let g = view.chunk_base + j;
    let mean = vec3<f32>(comp(j, 0u), comp(j, 1u), comp(j, 2u));
    let vm = view.viewmat;
    let p = (vm * vec4<f32>(mean, 1.0)).xyz;
    if (PROFILE == PROFILE_GSPLAT) {
        project_gsplat(j, g, mean, p);
        return;
    }
    if (!is_finite_f32(p.z) || p.z < 0.01 || p.z > 1e10) {
        cull(g);
        return;
    }
    let rz = 1.0 / p.z;
    let mx = view.intr.x * p.x * rz + view.intr.z;
    let my = view.intr.y * p.y * rz + view.intr.w;
    if (!is_finite_f32(mx) || !is_finite_f32(my)) {
        cull(g);
        return;
    }

    let s = scales(j);
    let rot = rotation(j);
    // EWA with gsplat's Jacobian clamp (30% beyond the image edge), evaluated as T T^T with
    // T = J W R S (2x3) and the determinant by Lagrange's identity, |t1|^2 |t2|^2 - (t1.t2)^2 =
    // |t1 x t2|^2: the textbook a*c - b*b cancels catastrophically for a needle (one huge axis),
    // which would make culling depend on the device's fused multiply-adds.
    let wmat = mat3x3<f32>(vm[0].xyz, vm[1].xyz, vm[2].xyz);
    let jac = jacobian(p, rz, false);
    let m2 = jac * (wmat * rot);
    let t1 = vec3<f32>(m2[0].x * s.x, m2[1].x * s.y, m2[2].x * s.z);
    let t2 = vec3<f32>(m2[0].y * s.x, m2[1].y * s.y, m2[2].y * s.z);
    let aa = (t1.x * t1.x + t1.y * t1.y) + t1.z * t1.z;
    let cc = (t2.x * t2.x + t2.y * t2.y) + t2.z * t2.z;
    let b = (t1.x * t2.x + t1.y * t2.y) + t1.z * t2.z;
    let xp = vec3<f32>(t1.y * t2.z - t1.z * t2.y, t1.z * t2.x - t1.x * t2.z, t1.x * t2.y - t1.y * t2.x);
    let a = aa + 0.3;
    let c = cc + 0.3;
    let det = (((xp.x * xp.x + xp.y * xp.y) + xp.z * xp.z) + 0.3 * (aa + cc)) + 0.09;

    let tiles_x = f32(view.tiles_x);
    let tiles_y = f32(view.tiles_y);
    var conic = vec3<f32>(0.0);
    var rect: vec2<u32>;
    if (!is_finite_f32(a) || !is_finite_f32(b) || !is_finite_f32(c) || !is_finite_f32(det)) {
        // Unbounded footprint: the whole screen, at peak opacity (conic zero).
        rect = pack_rect(0.0, 0.0, tiles_x, tiles_y);
    } else {
        // a or c can round negative for a huge covariance: culled like det <= 0 (sqrt would be NaN)
        if (det <= 0.0 || a < 0.0 || c < 0.0) {
            cull(g);
            return;
        }
        conic = vec3<f32>(c / det, -b / det, a / det);
        let rx = ceil(3.33 * sqrt(a));
        let ry = ceil(3.33 * sqrt(c));
        // Float-domain clamp before integer conversion: the saturating radius.
        let x0 = clamp(floor((mx - rx) / f32(TILE)) - view.tile_x0, 0.0, tiles_x);
        let x1 = clamp(ceil((mx + rx) / f32(TILE)) - view.tile_x0, 0.0, tiles_x);
        let y0 = clamp(floor((my - ry) / f32(TILE)) - view.tile_y0, 0.0, tiles_y);
        let y1 = clamp(ceil((my + ry) / f32(TILE)) - view.tile_y0, 0.0, tiles_y);
        if (x1 <= x0 || y1 <= y0) {
            cull(g);
            return;
        }
        rect = pack_rect(x0, y0, x1, y1);
    }

    emit(j, g, mean, vec2<f32>(mx, my), conic, rect, p.z);
}

// Opacity and colour, then the screen record of a drawn primitive.
fn emit(j: u32, g: u32, mean: vec3<f32>, xy: vec2<f32>, conic: vec3<f32>, rect: vec2<u32>, z: f32) {
    let opacity = sigmoid(comp(j, 10u));
    let d = mean - view.campos.xyz;
    let dir = d * rsqrt_ieee(dot(d, d));
    let rgb = sh_colour(j, dir);
    // The check inside the frame, on the primitives this view draws (what is culled anyway draws
    // nothing, corrupted or not), now that every value is read: a failing one is dropped, counted
    // and (FRAME_FLAGS) flagged.
    if (FRAME_CHECK != 0u && frame_check_fails(g)) {
        let p = g % view.n_total;
        if (FRAME_FLAGS != 0u) {
            atomicOr(&frame_out[OUT_FLAGS + (p >> 5u)], 1u << (p & 31u));
        }
        atomicAdd(&frame_out[OUT_DETECTED], 1u);
        atomicAdd(&frame_out[OUT_DETECTED_COPY], 1u);
        cull(g);
        return;
    }

    proj_xy[g] = xy;
    proj_conic[g] = vec4<f32>(conic, opacity);
    proj_rgb[g] = vec4<f32>(rgb, z);  // depth rides along for incremental re-compositing
    proj_rect[g] = rect;
    depth_keys[g] = bitcast<u32>(z);
    depth_vals[g] = g;
}

// ---- gsplat profile ----------------------------------------------------------------------------
// gsplat's CUDA arithmetic (ProjectionEWA3DGSFused.cu, Utils.cuh, IntersectTile.cu): comparisons
// that NaN fails do not cull, glm::min/max drop a NaN second operand, the covariance is formed
// explicitly (Sigma = M M^T, W Sigma W^T, J . J^T), det = a*c - b*b, and the radius goes through
// CUDA's float-to-int conversion (NaN -> 0: culled; >= 2^31 -> INT_MAX: the whole screen).

fn glm_min(a: f32, b: f32) -> f32 {
    return select(a, b, b < a);
}

fn glm_max(a: f32, b: f32) -> f32 {
    return select(a, b, a < b);
}

// x <= v and x >= v as comparisons that a NaN x fails (compilers may assume finite math).
fn le_num(x: f32, v: f32) -> bool {
    return !is_nan_f32(x) && x <= v;
}

fn ge_num(x: f32, v: f32) -> bool {
    return !is_nan_f32(x) && x >= v;
}

// CUDA (int32)x, back in float: NaN -> 0, saturating at +-2^31.
fn cuda_f2i(x: f32) -> f32 {
    if (is_nan_f32(x)) {
        return 0.0;
    }
    return clamp(x, -2147483648.0, 2147483648.0);
}

// sqrt, floor and ceil with CUDA's non-finite results (WGSL leaves them to the driver):
// sqrt(x < 0) = NaN, NaN and Inf pass through floor and ceil.
fn gs_sqrt(x: f32) -> f32 {
    if (is_nan_f32(x) || x < 0.0) {
        return bitcast<f32>(0x7fc00000u);
    }
    if (!is_finite_f32(x)) {
        return x;
    }
    return sqrt(x);
}

fn gs_floor(x: f32) -> f32 {
    return select(x, floor(x), is_finite_f32(x));
}

fn gs_ceil(x: f32) -> f32 {
    return select(x, ceil(x), is_finite_f32(x));
}

// Tile bound min(max(0, (int)v), tiles) of the full frame, then shifted into the viewport.
fn gs_tile(v: f32, full: f32, origin: f32, tiles: f32) -> f32 {
    return clamp(clamp(cuda_f2i(v), 0.0, full) - origin, 0.0, tiles);
}

fn project_gsplat(j: u32, g: u32, mean: vec3<f32>, p: vec3<f32>) {
    // NaN depth passes the near/far test (and is culled later by its NaN radius)
    if (!is_nan_f32(p.z) && (p.z < 0.01 || p.z > 1e10)) {
        cull(g);
        return;
    }
    let rz = 1.0 / p.z;
    let mx = view.intr.x * p.x * rz + view.intr.z;
    let my = view.intr.y * p.y * rz + view.intr.w;
    let s = scales(j);
    let rot = rotation(j);
    let m = mat3x3<f32>(rot[0] * s.x, rot[1] * s.y, rot[2] * s.z);
    let sigma3 = m * transpose(m);
    let wmat = mat3x3<f32>(view.viewmat[0].xyz, view.viewmat[1].xyz, view.viewmat[2].xyz);
    let cov_c = (wmat * sigma3) * transpose(wmat);
    let width = f32(view.width);
    let height = f32(view.height);
    let jac = jacobian(p, rz, true);
    let cov2 = (jac * cov_c) * transpose(jac);
    let a = cov2[0].x + 0.3;
    let c = cov2[1].y + 0.3;
    let det = a * c - cov2[0].y * cov2[1].x;
    if (le_num(det, 0.0)) {
        cull(g);
        return;
    }
    let inv = 1.0 / det;
    let conic = vec3<f32>(c * inv, -cov2[0].y * inv, a * inv);
    let rx = gs_ceil(3.33 * gs_sqrt(a));
    let ry = gs_ceil(3.33 * gs_sqrt(c));
    // radius_clip = 0 and the image-region mask: comparisons, which NaN fails
    if (le_num(rx, 0.0) && le_num(ry, 0.0)) {
        cull(g);
        return;
    }
    if (le_num(mx + rx, 0.0) || ge_num(mx - rx, width) || le_num(my + ry, 0.0) || ge_num(my - ry, height)) {
        cull(g);
        return;
    }
    // radii as int32 (NaN -> 0: culled by the tile intersection)
    let irx = cuda_f2i(rx);
    let iry = cuda_f2i(ry);
    if (irx <= 0.0 || iry <= 0.0) {
        cull(g);
        return;
    }
    let ts = f32(TILE);
    let full_x = f32((view.width + TILE - 1u) / TILE);
    let full_y = f32((view.height + TILE - 1u) / TILE);
    let tiles_x = f32(view.tiles_x);
    let tiles_y = f32(view.tiles_y);
    let x0 = gs_tile(gs_floor(mx / ts - irx / ts), full_x, view.tile_x0, tiles_x);
    let x1 = gs_tile(gs_ceil(mx / ts + irx / ts), full_x, view.tile_x0, tiles_x);
    let y0 = gs_tile(gs_floor(my / ts - iry / ts), full_y, view.tile_y0, tiles_y);
    let y1 = gs_tile(gs_ceil(my / ts + iry / ts), full_y, view.tile_y0, tiles_y);
    if (x1 <= x0 || y1 <= y0) {
        cull(g);
        return;
    }
    emit(j, g, mean, vec2<f32>(mx, my), conic, pack_rect(x0, y0, x1, y1), p.z);
}
