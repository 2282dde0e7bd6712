// #import common

// Decode every stored value of one model chunk to f32, plane by plane (component-major), so the
// host (and tests) can see exactly what the shaders read (render/decode.py; twin:
// model/encoding.py from_bits).

struct DecodeParams {
    count: u32,        // values to decode (planes * plane values)
    fmt: u32,          // FMT_FP32, FMT_FP16, FMT_BF16
    _p0: u32,
    _p1: u32,
};

@group(0) @binding(0) var<uniform> params: DecodeParams;
@group(0) @binding(1) var<storage, read> words: array<u32>;
@group(0) @binding(2) var<storage, read_write> values: array<f32>;

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= params.count) {
        return;
    }
    if (params.fmt == FMT_FP32) {
        values[i] = decode_value(words[i], false, FMT_FP32);
    } else {
        values[i] = decode_value(words[i >> 1u], (i & 1u) == 1u, params.fmt);
    }
}
