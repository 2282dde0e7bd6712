// #import common

// Batched bit flips (faults/flips.py; twin: xor_words): XOR a mask into listed words of one model
// chunk. The same call undoes itself, so restores are exact. The host merges masks per word, so
// no two threads touch one word.

struct FlipParams {
    count: u32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
};

struct Flip {
    word: u32,      // index of the u32 word in the chunk
    mask: u32,      // bits to XOR into it
};

@group(0) @binding(0) var<uniform> params: FlipParams;
@group(0) @binding(1) var<storage, read> flips: array<Flip>;
@group(0) @binding(2) var<storage, read_write> words: array<u32>;

@compute @workgroup_size(WG)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= params.count) {
        return;
    }
    let f = flips[i];
    words[f.word] = words[f.word] ^ f.mask;
}
