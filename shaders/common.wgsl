// Shared helpers, prepended to every stage by seuwgpu/gpu/device.py.
// Non-finite values are detected on the raw bits: compilers may assume finite math.

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

// Decode one stored value. PRECISION: 0 = fp32, 1 = fp16, 2 = bf16 (pipeline-overridable
// constant declared by stages that read the model). `word` holds the value's u32 word and
// `hi` selects the high half for 16-bit formats.
fn decode_value(word: u32, hi: bool, precision: u32) -> f32 {
    if (precision == 0u) {
        return bitcast<f32>(word);
    }
    var h = word & 0xffffu;
    if (hi) {
        h = word >> 16u;
    }
    if (precision == 2u) {
        return bitcast<f32>(h << 16u);
    }
    return f16_bits_to_f32(h);
}

fn sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}

// Linear workgroup id for 2-D dispatches made by dispatch_dims().
fn linear_wg(wg: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wg.y * nwg.x + wg.x;
}
