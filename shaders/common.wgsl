// Shared helpers, imported by every stage (`// #import common`), after the generated constants
// header (TILE, WG, MAX_GROUPS_X, FMT_*: seuwgpu/gpu/constants.py) that seuwgpu/gpu/device.py
// prepends.
// Non-finite values are detected on the raw bits: compilers may assume finite math.

const TILE_PIXELS: u32 = TILE * TILE;

fn is_finite_f32(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn is_nan_f32(x: f32) -> bool {
    let b = bitcast<u32>(x);
    return (b & 0x7f800000u) == 0x7f800000u && (b & 0x007fffffu) != 0u;
}

// Exact fp16 -> f32 by bit manipulation (unpack2x16float leaves NaN/Inf and subnormal handling
// to the driver; this is the same on every backend and matches numpy bit for bit).
fn f16_bits_to_f32(h: u32) -> f32 {
    let s = (h & 0x8000u) << 16u;
    let e = (h >> 10u) & 0x1fu;
    let m = h & 0x3ffu;
    if (e == 0x1fu) {
        return bitcast<f32>(s | 0x7f800000u | (m << 13u));
    }
    if (e == 0u) {
        // subnormal or zero: m * 2^-24, exact in f32
        return bitcast<f32>(s | bitcast<u32>(f32(m) * 5.9604644775390625e-8));
    }
    return bitcast<f32>(s | ((e + 112u) << 23u) | (m << 13u));
}

// Decode one stored value. fmt: FMT_FP32, FMT_FP16 or FMT_BF16.
// `hi` selects the high half for 16-bit formats.
fn decode_value(word: u32, hi: bool, fmt: u32) -> f32 {
    if (fmt == FMT_FP32) {
        return bitcast<f32>(word);
    }
    var h = word & 0xffffu;
    if (hi) {
        h = word >> 16u;
    }
    if (fmt == FMT_BF16) {
        return bitcast<f32>(h << 16u);
    }
    return f16_bits_to_f32(h);
}

// exp with IEEE edge cases pinned down (WGSL leaves overflow, non-finite inputs and subnormal
// results to the driver: lavapipe flushes these, other devices may not; docs/renderer.md rule 4).
fn exp_ieee(x: f32) -> f32 {
    if (is_nan_f32(x)) {
        return x;
    }
    if (x > EXP_MAX) {
        return bitcast<f32>(0x7f800000u);
    }
    if (x < EXP_MIN) {
        return 0.0;  // results below the smallest normal: flushed on every device
    }
    return exp(x);
}

// 1/sqrt(x) with rsqrt(0) = +Inf, rsqrt(+Inf) = 0, NaN -> NaN (glm's normalize relies on these).
fn rsqrt_ieee(x: f32) -> f32 {
    if (is_nan_f32(x)) {
        return x;
    }
    if (x == 0.0) {
        return bitcast<f32>(0x7f800000u);
    }
    if (!is_finite_f32(x)) {
        return 0.0;
    }
    return inverseSqrt(x);
}

// Logistic, stable for both signs; sigmoid(+Inf) = 1, sigmoid(-Inf) = 0, NaN stays NaN.
fn sigmoid(x: f32) -> f32 {
    if (is_nan_f32(x)) {
        return x;
    }
    if (x >= 0.0) {
        return 1.0 / (1.0 + exp_ieee(-x));
    }
    let e = exp_ieee(x);
    return e / (1.0 + e);
}

// Linear workgroup id for 2-D dispatches made by dispatch_dims().
fn linear_wg(wg: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wg.y * nwg.x + wg.x;
}

// Linear invocation id of a one-thread-per-element kernel (@workgroup_size(WG)) under dispatch_dims().
fn linear_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

// Per-view tile-binning parameters shared by bin.wgsl and composite.wgsl (render/bin.py).
struct Binning {
    n_total: u32,       // primitives in the model
    tiles_x: u32,
    n_tiles: u32,
    capacity: u32,      // intersection buffer length: writes past it are dropped and the frame re-run
    stats_index: u32,   // the slot of this list's intersection total in the stats buffer
    width: u32,         // viewport size in pixels (the output image)
    height: u32,
    origin: u32,        // viewport origin in pixels (x | y << 16), tile-aligned; 0 for a full frame
    views: u32,         // frames binned into one list (render/renderer.py batched views), else 1
    frame: u32,         // the first frame's slot in the image (and its views' totals in stats)
    background: vec4<f32>,  // w: 0, the zero blend.wgsl's `unfused` reads
};

// Support-guard box of one stored component (faults/guard.py Box): bounds as f32 and as the
// stored bits written back by the scrub (fp32 word or 16-bit half).
struct Bound {
    lo: f32,
    hi: f32,
    lo_bits: u32,
    hi_bits: u32,
};

// Field index (means 0, log_scales 1, quats 2, opacity 3, sh_dc 4, sh_rest 5) of a flat component.
fn field_of(c: u32) -> u32 {
    if (c < 3u) { return 0u; }
    if (c < 6u) { return 1u; }
    if (c < 10u) { return 2u; }
    if (c < 11u) { return 3u; }
    if (c < 14u) { return 4u; }
    return 5u;
}

// Support-guard rule for one decoded value against its box [lo, hi]: NaN -> lo (the smallest,
// least visible value for log-scale and opacity), below -> lo, above -> hi (so -Inf -> lo,
// +Inf -> hi). Returns 0 inside the box (value untouched, bit for bit), 1 for lo, 2 for hi.
fn guard_side(v: f32, lo: f32, hi: f32) -> u32 {
    if (is_nan_f32(v)) {
        return 1u;
    }
    if (v < lo) {
        return 1u;
    }
    if (v > hi) {
        return 2u;
    }
    return 0u;
}

// ---- footprint bounds, shared by binning and compositing (docs/renderer.md, "Exact binning") ----

fn inf_f32() -> f32 {
    return bitcast<f32>(0x7f800000u);
}

// Sigma beyond which a record of opacity o cannot reach alpha >= 1/255 for certain: ln(255 o) +
// 0.01 (a margin far above exp's error); -Inf when o < 0.001, where alpha < 1/255 for every
// sigma >= 0; +Inf (never cut) when o is NaN or |o| > 1e30.
fn cut_of(o: f32) -> f32 {
    if ((bitcast<u32>(o) & 0x7fffffffu) > 0x7149f2cau) {
        return inf_f32();  // NaN, infinite or |o| > 1e30: never cut
    }
    if (o < 0.001) {
        return -inf_f32();
    }
    return log(255.0 * o) + 0.01;
}

// Records whose float evaluation of sigma(dx, dy) = 0.5 (A dx^2 + C dy^2) + B dx dy is provably
// within 1e-4 of its value: conic (A, B, C) with A, C in [1e-12, 1e6], |B| <= 1e6,
// B^2 <= 0.99 A C (no overflow, no cancellation beyond a factor 200), means within 1e6 px (dx, dy
// exact to 0.06 px) and a finite cut. No footprint bound is derived for any other record.
fn footprint_bounded(xy: vec2<f32>, co: vec4<f32>, cut: f32) -> bool {
    let A = co.x;
    let B = co.y;
    let C = co.z;
    if (!is_finite_f32(A) || !is_finite_f32(B) || !is_finite_f32(C) || !is_finite_f32(xy.x) || !is_finite_f32(xy.y)) {
        return false;
    }
    return A >= 1e-12 && C >= 1e-12 && A <= 1e6 && C <= 1e6 && abs(B) <= 1e6 && abs(xy.x) <= 1e6
        && abs(xy.y) <= 1e6 && cut < 1e30 && B * B <= 0.99 * (A * C);
}

// Exact binning's footprint of a record (screen mean xy; conic A, B, C and opacity in co): the
// ellipse sigma(u) = 0.5 (A ux^2 + C uy^2) + B ux uy <= S around the mean, S = 1.05 max(cut, 1e-3)
// (a 5% margin over sigma's float error). kind REACH_NONE: no pixel can be reached (cut < 0:
// sigma < 0 and alpha < 1/255 are both skipped); REACH_ALL: no bound (footprint_bounded fails:
// the whole rectangle, e.g. an unbounded footprint); REACH_ELLIPSE: the ellipse.
const REACH_NONE: u32 = 0u;
const REACH_ELLIPSE: u32 = 1u;
const REACH_ALL: u32 = 2u;

struct Reach {
    kind: u32,
    xy: vec2<f32>,
    co: vec4<f32>,
    s2: f32,     // 2 S
    d: f32,      // A C - B^2 (> 0.01 A C here)
    ry: f32,     // |uy| <= ry on the ellipse
    k: f32,      // uy of the ellipse's rightmost point = -B k (leftmost: +B k)
};

fn reach(xy: vec2<f32>, co: vec4<f32>) -> Reach {
    var r = Reach(REACH_ALL, xy, co, 0.0, 0.0, 0.0, 0.0);
    let cut = cut_of(co.w);
    if (!footprint_bounded(xy, co, cut)) {
        return r;
    }
    if (cut < 0.0) {
        r.kind = REACH_NONE;
        return r;
    }
    r.kind = REACH_ELLIPSE;
    r.s2 = 2.0 * (1.05 * max(cut, 1e-3));
    r.d = co.x * co.z - co.y * co.y;
    r.ry = sqrt(r.s2 * co.x / r.d);
    r.k = sqrt(r.s2 / (r.d * co.z));
    return r;
}

// ux of the ellipse's edge at height uy (side +1 right, -1 left), for |uy| <= ry.
fn ellipse_edge(r: Reach, uy: f32, side: f32) -> f32 {
    let disc = max(r.s2 * r.co.x - r.d * uy * uy, 0.0);
    return (-r.co.y * uy + side * sqrt(disc)) / r.co.x;
}

// Pixel-x interval (full-frame) reached within the band of pixel-centre rows [y0, y1], both
// widened by 1/8 px (the rounding of dx = mx - px: at most 1/16 px for the |mx| <= 1e6 and pixel
// centres below 2^21 of bounded records): the x-projection of the band's slice of
// the ellipse (convex: the right edge is concave in uy, so its maximum over the band is at the
// rightmost point's uy clamped into it; the left edge likewise). Empty (x > y) when the band
// misses the ellipse.
fn band_extent(r: Reach, y0: f32, y1: f32) -> vec2<f32> {
    let lo = max(y0 - 0.125 - r.xy.y, -r.ry);
    let hi = min(y1 + 0.125 - r.xy.y, r.ry);
    if (lo > hi) {
        return vec2<f32>(1.0, 0.0);
    }
    let right = ellipse_edge(r, clamp(-r.co.y * r.k, lo, hi), 1.0);
    let left = ellipse_edge(r, clamp(r.co.y * r.k, lo, hi), -1.0);
    return vec2<f32>(r.xy.x + left - 0.125, r.xy.x + right + 0.125);
}

// Tile columns [c0, c1) of the tile row whose first pixel row is y (full-frame), within the
// rectangle's columns [x0, x1), that a record may reach; fx: the viewport's first pixel column.
// Exact for the (margined) ellipse: a tile is kept when some pixel centre of it lies in the
// row's interval.
fn row_tiles(r: Reach, y: f32, fx: f32, x0: u32, x1: u32) -> vec2<u32> {
    if (r.kind == REACH_ALL) {
        return vec2<u32>(x0, x1);
    }
    let e = band_extent(r, y + 0.5, y + f32(TILE) - 0.5);
    if (r.kind == REACH_NONE || e.x > e.y) {
        return vec2<u32>(x0, x0);
    }
    let ts = f32(TILE);
    let c0 = clamp(ceil((e.x - fx - (ts - 0.5)) / ts), f32(x0), f32(x1));
    let c1 = clamp(floor((e.y - fx - 0.5) / ts) + 1.0, f32(x0), f32(x1));
    return vec2<u32>(u32(c0), u32(max(c0, c1)));
}
