// Shared helpers, compiled into every stage after the generated constants header (TILE, WG,
// MAX_GROUPS_X, FMT_*: seuwgpu/gpu/constants.py) by seuwgpu/gpu/device.py.
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

// exp with IEEE edge cases pinned down (WGSL leaves overflow and non-finite inputs to the driver).
fn exp_ieee(x: f32) -> f32 {
    if (is_nan_f32(x)) {
        return x;
    }
    if (x > 88.72283) {
        return bitcast<f32>(0x7f800000u);
    }
    if (x < -103.97208) {
        return 0.0;
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
    stats_index: u32,   // this view's slot in the stats buffer (intersection total)
    width: u32,         // viewport size in pixels (the output image)
    height: u32,
    origin: u32,        // viewport origin in pixels (x | y << 16), tile-aligned; 0 for a full frame
    background: vec4<f32>,
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
