// #import composite_lanes

// Single-upset variants (render/variants.py VariantCompositing), in the lanes shape:
// - variants: a tile of a single-upset variant, re-composited from the clean frame's tile list
//   with the corrupted primitive removed and its re-projected record merged in at its depth
//   (render/incremental.py; equal to a full re-render bit for bit), one chunk per dispatch. Only
//   the pixels that the clean or the corrupted record reaches are re-blended when both lists are
//   one chunk; the others are copied. composite.wgsl's main and chunks leave every pair's pixel
//   box in isect_box when KEEP_BOXES (a frame kept with the clean state), so a variant tile
//   stages only the entries whose box meets the bounding box of its re-blended pixels, and reads
//   nothing of the others (they skip those pixels for certain);
// - checkpoints: the pass that keeps a clean frame's checkpoints and pixel ends (below).
// Both run blend.wgsl's per-pixel rule over composite_lanes.wgsl's pixels, as the full-frame
// entry points do, so their arithmetic is identical bit for bit.

struct Recomp {
    width: u32,
    height: u32,
    tiles_x: u32,
    n_tiles: u32,
    n_prims: u32,       // stride of the per-view clean records (the model's primitives, padded)
    n_variants: u32,    // stride of the per-view variant arrays
    capacity: u32,      // stride of the per-view clean tile lists
    n_entries: u32,
    background: vec4<f32>,  // w: 0 (blend.wgsl unfused)
    chunk_pass: u32,    // the chunk of every entry's list this dispatch composites
    ckpt_every: u32,    // list positions between checkpoints (a multiple of the round; divides CHUNK_PAIRS)
    first_view: u32,    // the kept view group bound (kv_isect, kv_box, kv_xy, kv_conic, kv_rgb start there)
    first_entry: u32,   // this dispatch's entries: first_entry .. n_entries - 1 (all of view group's)
};

// Offsets of view v's clean records and tile list in the bound view group.
fn prim_base(v: u32) -> u32 {
    return (v - rc.first_view) * rc.n_prims;
}

fn list_base(v: u32) -> u32 {
    return (v - rc.first_view) * rc.capacity;
}

@group(0) @binding(10) var<uniform> rc: Recomp;
// One tile of one variant to re-composite (the checkpoint pass: one tile of a clean view).
struct VariantEntry {
    variant: u32,       // index of the variant's records (per view, n_variants apart)
    view: u32,
    tile: u32,
    prim: u32,          // the primitive the variant changes
};

@group(0) @binding(11) var<storage, read> entries: array<VariantEntry>;
@group(0) @binding(12) var<storage, read> kv_ranges: array<vec2<u32>>;
@group(0) @binding(13) var<storage, read> kv_isect: array<u32>;
@group(0) @binding(14) var<storage, read> kv_xy: array<vec2<f32>>;
@group(0) @binding(15) var<storage, read> kv_conic: array<vec4<f32>>;
@group(0) @binding(16) var<storage, read> kv_rgb: array<vec4<f32>>;     // w = depth
@group(0) @binding(17) var<storage, read> var_xy: array<vec2<f32>>;
@group(0) @binding(18) var<storage, read> var_conic: array<vec4<f32>>;
@group(0) @binding(19) var<storage, read> var_rgb: array<vec4<f32>>;
@group(0) @binding(20) var<storage, read> var_rect: array<vec2<u32>>;
@group(0) @binding(21) var<storage, read_write> slabs: array<vec4<f32>>;
@group(0) @binding(24) var<storage, read_write> variant_ended: array<u32>;  // between chunk dispatches
@group(0) @binding(25) var<storage, read_write> slab_changed: array<u32>;  // box of the pixels that differ from clean
// Clean frame: per pixel, the last list position its value depends on (its end: where it stopped,
// or the last position of the chunk whose merge ended it), or for a pixel that never ends OPEN |
// (1 + the last position of a record that reaches it; 0: none does). main writes the stops of
// lists of one chunk (NEVER where none: read as open, reached anywhere); the checkpoint pass
// writes every listed tile's (render/incremental.py).
@group(0) @binding(26) var<storage, read_write> kv_stop: array<u32>;
// Clean frame's checkpoints: the pixels' state (rgb, T) at list positions j * ckpt_every,
// 0 < j * ckpt_every < n: at a chunk's first position the merged state of the chunks before it,
// elsewhere the state of the chunk's own walk. Tile t of view v keeps them at slots
// ckpt_base[v * n_tiles + t] + j - 1 (TILE_PIXELS vec4 each).
@group(0) @binding(27) var<storage, read> ckpt_base: array<u32>;
@group(0) @binding(28) var<storage, read_write> ckpt_states: array<vec4<f32>>;
// Per entry, the chunk of its list its next pass walks (FINISHED once it wrote its pixels).
@group(0) @binding(29) var<storage, read_write> entry_next: array<u32>;
const FINISHED: u32 = 0xffffffffu;
// Clean frame: each later chunk's own result (c.rgb, t; t negated where the chunk stopped early)
// per pixel, for the chunks 1 .. of every list of several chunks, chunk j of tile t of view v at
// slot chunk_base[v * n_tiles + t] + j - 1: a variant merges them where its change leaves a
// chunk's records the same for a pixel, instead of walking it again.
@group(0) @binding(36) var<storage, read> chunk_base: array<u32>;
@group(0) @binding(37) var<storage, read_write> chunk_states: array<vec4<f32>>;
var<workgroup> s_changed: array<atomic<u32>, 4>;  // min col, max col, min row, max row
@group(0) @binding(22) var<storage, read> clean_image: array<vec4<f32>>;  // [K, H, W]
@group(0) @binding(23) var<storage, read> kv_box: array<u32>;              // pixel box per kept pair

const NONE: u32 = 0xffffffffu;
const OPEN: u32 = 0x80000000u;

// Whether clean list position x is at or before the pixels' ends (kv_stop, above): for a pixel
// that never ends, whether a record at x can still reach it.
fn within(x: vec4<u32>, stop: vec4<u32>) -> vec4<bool> {
    return select(x <= stop, x < (stop & vec4<u32>(~OPEN)), (stop & vec4<u32>(OPEN)) != vec4<u32>(0u));
}
// The checkpoint pass's pipeline (a constant there: CPU Vulkan would run both sides of a branch).
override RECORD: bool = false;

// Tile-local bounds of the pixels still to blend (x0 | x1 << 8 | y0 << 16 | y1 << 24 once
// gathered; empty when x0 > x1).
var<workgroup> s_active: array<atomic<u32>, 4>;  // min col, max col, min row, max row

var<workgroup> s_count: array<u32, LANES>;  // staged entries per invocation, then their offsets
var<workgroup> s_kept: u32;
const ROUND_MAX: u32 = 4u * BATCH;  // list entries a variant tests per round
var<workgroup> s_kept_entry: array<u32, ROUND_MAX>;  // entries of a round to stage, in list order

// Offsets of a compaction in list order: each invocation passes how many of its PER_LANE
// consecutive entries it keeps; returns (its first slot, the batch's total, uniform).
fn compact(li: u32, kept: u32) -> vec2<u32> {
    s_count[li] = kept;
    workgroupBarrier();
    if (li == 0u) {
        var sum = 0u;
        for (var t = 0u; t < LANES; t = t + 1u) {
            let c = s_count[t];
            s_count[t] = sum;
            sum = sum + c;
        }
        s_kept = sum;
    }
    let total = workgroupUniformLoad(&s_kept);
    return vec2<u32>(s_count[li], total);
}

// Position in the clean tile list of entry i of the variant's list.
fn clean_pos(i: u32, insert: u32, removed: u32) -> u32 {
    var j = i;
    if (insert != NONE && i > insert) { j = j - 1u; }
    if (removed != NONE && j >= removed) { j = j + 1u; }
    return j;
}

// Whether two pixel boxes share a pixel.
fn boxes_meet(a: u32, b: u32) -> bool {
    let x0 = max(a & 0xffu, b & 0xffu);
    let x1 = min((a >> 8u) & 0xffu, (b >> 8u) & 0xffu);
    let y0 = max((a >> 16u) & 0xffu, (b >> 16u) & 0xffu);
    let y1 = min(a >> 24u, b >> 24u);
    return x0 <= x1 && y0 <= y1;
}

// (n virtual, insert position or NONE, removed position or NONE, 1 if the clean or the virtual
// list has more than one chunk)
var<workgroup> s_list: vec4<u32>;
var<workgroup> s_insert_at: u32;  // the corrupted record's place in the clean list (before that entry)
// (first position where the lists differ or NONE, the checkpoint the walk resumes from)
var<workgroup> s_walk: vec2<u32>;
var<workgroup> s_status: u32;  // the chunk this pass walks, or FINISHED
var<workgroup> s_need: atomic<u32>;  // some pixel must walk the chunk being decided
var<workgroup> s_needed: u32;  // s_need, read once every invocation has voted
// Clean positions of the records that the change moves across a chunk boundary: first, end
// (exclusive), every CHUNK_PAIRS (none when first >= end).
var<workgroup> s_cross: vec2<u32>;

// Lanes of the quad that a record takes part in (the same arithmetic and skip rules as
// blend_batch). A pixel that neither the clean nor the corrupted record reaches composites
// exactly as the clean frame did, so it is copied instead of re-blended.
fn contributes(xy: vec2<f32>, co: vec4<f32>, q: Quad) -> vec4<bool> {
    return alpha_of(sigma_of(xy, co, q), co.w).hit;
}

// (key, index) ordering of the depth sort: depth bits, ties by primitive index.
fn before(ka: u32, ia: u32, kb: u32, ib: u32) -> bool {
    return ka < kb || (ka == kb && ia < ib);
}

fn clean_key(v: u32, g: u32) -> u32 {
    return bitcast<u32>(kv_rgb[prim_base(v) + g].w);
}

// number of list entries ordered before (key, idx)
fn count_before(v: u32, start: u32, end: u32, key: u32, idx: u32) -> u32 {
    var lo = start;
    var hi = end;
    let base = list_base(v);
    while (lo < hi) {
        let mid = (lo + hi) >> 1u;
        let g = kv_isect[base + mid];
        if (before(clean_key(v, g), g, key, idx)) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - start;
}

// A variant's running chunks between dispatches: (rgb, T) in its slab, and which pixels ended in
// `variant_ended` (one word per invocation of the entry, bit QUAD j + i for Quad j, lane i; a
// flag, not a sign on T: T may be NaN).
fn write_variant_state(e: u32, li: u32, p: ptr<function, Pixels>, col: u32, row0: u32) {
    var ended = 0u;
    for (var j = 0u; j < QPI; j = j + 1u) {
        let q = (*p).q[j];
        for (var i = 0u; i < QUAD; i = i + 1u) {
            slabs[slot_pixel(e, col, row0, j, i)] = lane_state(q, i);
            ended = ended | (u32(q.done[i]) << (QUAD * j + i));
        }
    }
    variant_ended[e * LANES + li] = ended;
}

fn read_variant_state(e: u32, li: u32, col: u32, row0: u32, p0: Pixels) -> Pixels {
    var p = p0;
    let ended = variant_ended[e * LANES + li];
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            p.q[j] = with_lane_state(p.q[j], i, slabs[slot_pixel(e, col, row0, j, i)]);
        }
        p.q[j].done = (vec4<u32>(ended >> (QUAD * j)) & vec4<u32>(1u, 2u, 4u, 8u)) != vec4<u32>(0u);
    }
    return p;
}

// The pixels' (rgb, T) into checkpoint slot `slot`, and back (the pixels keep their done flags:
// only pixels alive at a checkpoint read it).
fn write_checkpoint(slot: u32, p: ptr<function, Pixels>, col: u32, row0: u32) {
    for (var j = 0u; j < QPI; j = j + 1u) {
        let q = (*p).q[j];
        for (var i = 0u; i < QUAD; i = i + 1u) {
            ckpt_states[slot_pixel(slot, col, row0, j, i)] = lane_state(q, i);
        }
    }
}

fn read_checkpoint(slot: u32, col: u32, row0: u32, p0: Pixels) -> Pixels {
    var p = p0;
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            p.q[j] = with_lane_state(p.q[j], i, ckpt_states[slot_pixel(slot, col, row0, j, i)]);
        }
    }
    return p;
}

// The box of the pixels still to blend (a record whose box misses it is not read); s_active must
// have been reset before the last barrier.
fn live_box(p: ptr<function, Pixels>, col: u32, row0: u32) -> u32 {
    for (var j = 0u; j < QPI; j = j + 1u) {
        let left = !(*p).q[j].done;
        let rows = select(vec4<u32>(0xffu), vec4<u32>(row0 + QUAD * j) + vec4<u32>(0u, 1u, 2u, 3u), left);
        if (any(left)) {
            atomicMin(&s_active[0], col);
            atomicMax(&s_active[1], col);
            atomicMin(&s_active[2], min(min(rows.x, rows.y), min(rows.z, rows.w)));
            let top = select(vec4<u32>(0u), rows, left);
            atomicMax(&s_active[3], max(max(top.x, top.y), max(top.z, top.w)));
        }
    }
    workgroupBarrier();
    return atomicLoad(&s_active[0]) | (atomicLoad(&s_active[1]) << 8u) | (atomicLoad(&s_active[2]) << 16u)
        | (atomicLoad(&s_active[3]) << 24u);
}

// The invocation's pixels of the entry's tile (first pixel tile0): column col, rows row0 ..
fn entry_pixels(tile0: vec2<u32>, col: u32, row0: u32) -> Pixels {
    return make_pixels(tile0.x + col, tile0.y + row0, vec2<u32>(0u), vec2<u32>(rc.width, rc.height));
}

fn reset_active() {
    atomicStore(&s_active[0], 0xffu);
    atomicStore(&s_active[1], 0u);
    atomicStore(&s_active[2], 0xffu);
    atomicStore(&s_active[3], 0u);
}

// blend_batch over the m staged records of a round, noting in `stops` the list position (the
// round's listed entry sb + k) of the record each pixel stopped at, and in `last` 1 + that of
// the last record that reached it.
fn blend_batch_stops(p: ptr<function, Pixels>, col: u32, row0: u32, m: u32, sb: u32, stops: ptr<function, Stops>,
                     last: ptr<function, Stops>) {
    if (all_pixels_done(p)) {
        return;
    }
    for (var k = 0u; k < m; k = k + 1u) {
        let done0 = (*p).q[0].done;
        let done1 = (*p).q[1].done;
        let at = vec4<u32>(s_kept_entry[sb + k]);
        let bx = s_box[k];
        if (col >= (bx & 0xffu) && col <= ((bx >> 8u) & 0xffu) && row0 + SPAN - 1u >= ((bx >> 16u) & 0xffu)
            && row0 <= bx >> 24u) {
            let st = s_pos[k];
            let co = s_conic[k];
            (*last)[0] = select((*last)[0], at + 1u, contributes(st.xy, co, (*p).q[0]) & !done0);  // QPI = 2
            (*last)[1] = select((*last)[1], at + 1u, contributes(st.xy, co, (*p).q[1]) & !done1);
        }
        let finished = blend_record(p, col, row0, k);
        (*stops)[0] = select((*stops)[0], at, (*p).q[0].done & !done0);  // QPI = 2
        (*stops)[1] = select((*stops)[1], at, (*p).q[1].done & !done1);
        if (finished) {
            break;
        }
    }
}

// The list a walk reads: view v's clean tile list (starting at `first` in kv_isect) with clean
// position `removed` dropped and a record (xy, co, rgb, pixel box bx) inserted at position
// `insert` of the resulting list (NONE: neither).
struct Walk {
    v: u32,
    first: u32,
    insert: u32,
    removed: u32,
    xy: vec2<f32>,
    co: vec4<f32>,
    rgb: vec4<f32>,
    bx: u32,
};

// Blend positions [start, hi) of the walk's list into p (start, hi uniform). The list is walked in
// rounds of `round` entries (up to ROUND_MAX, dividing CHUNK_PAIRS): each invocation tests round /
// LANES consecutive entries' pixel boxes against `live`; those that meet it are listed in list
// order (an exclusive scan of the per-invocation counts), then staged and blended BATCH at a time,
// so the blend loop never visits the others. Listing before reading the records, and rounds of
// many entries, matter on CPU Vulkan, where a branch never skips code and a barrier costs
// microseconds. A pixel ends at the first round that starts at or past its `limit` (past the
// last record that can reach it; NONE: no limit). RECORD (the checkpoint pass): `stops` receives
// where each pixel stopped, `last` 1 + where a record last reached it, and each round that ends
// on a checkpoint position inside [start, hi) keeps the pixels' state at slot
// ckpt0 + position / ckpt_every - 1.
fn walk_list(p: ptr<function, Pixels>, li: u32, col: u32, row0: u32, start: u32, hi: u32, live0: u32, w: Walk,
             limit: Stops, stops: ptr<function, Stops>, last: ptr<function, Stops>, ckpt0: u32) {
    var round = BATCH;
    if (CHUNK_PAIRS % ROUND_MAX == 0u) {
        round = ROUND_MAX;
    } else if (CHUNK_PAIRS % (2u * BATCH) == 0u) {
        round = 2u * BATCH;
    }
    let per_lane = round / LANES;
    var live = live0;
    var rounds = (hi - min(start, hi) + round - 1u) / round;
    if (workgroupUniformLoad(&s_done) == LANES) {
        rounds = 0u;  // no pixel left to blend: copied from the clean frame, or ended before
    }
    var ended = false;
    for (var rd = 0u; rd < rounds && !ended; rd = rd + 1u) {
        let first = start + rd * round;
        if (!RECORD && rd > 0u) {
            // pixels past every record that can reach them: ended
            let was = all_pixels_done(p);
            for (var j = 0u; j < QPI; j = j + 1u) {
                (*p).q[j].done = (*p).q[j].done | (limit[j] <= vec4<u32>(first));
            }
            if (!was && all_pixels_done(p)) {
                atomicAdd(&s_done, 1u);
            }
            if (all_done(li)) {
                break;
            }
            // the box of the pixels still to blend shrinks as they end
            if (li == 0u) {
                reset_active();
            }
            workgroupBarrier();
            live = live_box(p, col, row0);
        }
        var kept_bits = 0u;
        for (var s = 0u; s < per_lane; s = s + 1u) {
            let i = first + li * per_lane + s;
            var bx = w.bx;
            if (i != w.insert) {
                bx = kv_box[list_base(w.v) + w.first + clean_pos(min(i, hi - 1u), w.insert, w.removed)];
            }
            kept_bits = kept_bits | (u32(i < hi && boxes_meet(bx, live)) << s);
        }
        let at_m = compact(li, countOneBits(kept_bits));
        let m = at_m.y;
        var bits = kept_bits;
        var at = at_m.x;
        while (bits != 0u) {
            s_kept_entry[at] = first + li * per_lane + firstTrailingBit(bits);
            bits = bits & (bits - 1u);
            at = at + 1u;
        }
        workgroupBarrier();
        for (var sb = 0u; sb < m; sb = sb + BATCH) {
            let mb = min(m - sb, BATCH);
            for (var slot = li; slot < mb; slot = slot + LANES) {
                let i = s_kept_entry[sb + slot];
                if (i == w.insert) {
                    stage_boxed(slot, w.xy, w.co, w.rgb, w.bx);
                } else {
                    let at = list_base(w.v) + w.first + clean_pos(i, w.insert, w.removed);
                    let og = prim_base(w.v) + kv_isect[at];  // its box: the clean frame's, for this very pair
                    stage_boxed(slot, kv_xy[og], kv_conic[og], kv_rgb[og], kv_box[at]);
                }
            }
            workgroupBarrier();
            if (RECORD) {
                blend_batch_stops(p, col, row0, mb, sb, stops, last);
            } else {
                blend_batch(p, col, row0, mb);
            }
            if (all_done(li)) {
                ended = true;
                break;
            }
        }
        let end = first + round;
        if (RECORD && !ended && end < hi && end % rc.ckpt_every == 0u) {
            write_checkpoint(ckpt0 + end / rc.ckpt_every - 1u, p, col, row0);
        }
    }
}

fn chunk_bit(j: u32) -> u32 {
    return 1u << min(j, 31u);
}

// Whether a pixel must walk chunk j again: its records there change (walks: chunk_bit), or the
// clean frame has no result of that chunk for it (it had ended before; a closed end below jC).
fn must_walk(walks: vec4<u32>, stop: vec4<u32>, j: u32) -> vec4<bool> {
    let bit = vec4<u32>(chunk_bit(j));
    let from31 = vec4<bool>(j >= 31u) & (walks >= vec4<u32>(0x80000000u));
    let ended = ((stop & vec4<u32>(OPEN)) == vec4<u32>(0u)) & (stop < vec4<u32>(j * CHUNK_PAIRS));
    return ((walks & bit) != vec4<u32>(0u)) | from31 | ended;
}

// p with the `take` lanes replaced by chunk j >= 1's clean result (c, t, stopped, with t
// negated where it stopped as write_slab stores it; a chunk past the clean list's last holds none
// of the lanes' records: c = 0, t = 1).
fn take_clean_chunk(p0: Pixels, take: array<vec4<bool>, QPI>, slot0: u32, j: u32, clean_chunks: u32, col: u32,
                    row0: u32) -> Pixels {
    var p = p0;
    if (j >= clean_chunks) {
        for (var q = 0u; q < QPI; q = q + 1u) {
            p.q[q].r = select(p.q[q].r, vec4<f32>(0.0), take[q]);
            p.q[q].g = select(p.q[q].g, vec4<f32>(0.0), take[q]);
            p.q[q].b = select(p.q[q].b, vec4<f32>(0.0), take[q]);
            p.q[q].T = select(p.q[q].T, vec4<f32>(1.0), take[q]);
            p.q[q].done = select(p.q[q].done, vec4<bool>(false), take[q]);
        }
        return p;
    }
    let slot = slot0 + j - 1u;
    for (var q = 0u; q < QPI; q = q + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            if (take[q][i]) {
                let st = chunk_states[slot_pixel(slot, col, row0, q, i)];
                let stopped = st.w < 0.0;  // read_slab's rule: a NaN t (never stopped) as it is
                p.q[q].r[i] = st.x;
                p.q[q].g[i] = st.y;
                p.q[q].b[i] = st.z;
                p.q[q].T[i] = select(st.w, -st.w, stopped);
                p.q[q].done[i] = stopped;
            }
        }
    }
    return p;
}

// Recount s_done over the invocations' pixels (after a merge): true, uniformly, when all are done.
fn all_pixels_finished(p: ptr<function, Pixels>, li: u32) -> bool {
    workgroupBarrier();
    if (li == 0u) {
        atomicStore(&s_done, 0u);
    }
    workgroupBarrier();
    count_if_done(p);
    return all_done(li);
}

// A tile of a single-upset variant, re-composited from the clean frame's kept state (equal to a
// full re-render of the variant, bit for bit; docs/renderer.md "Incremental re-compositing"):
// - the lists agree before position a = min(removed, insert), so the walk resumes from the clean
//   frame's last checkpoint at or before a (render/incremental.py CleanViews keeps them), in the
//   chunk that holds it, and runs to where every re-blended pixel ends;
// - a pixel is copied from the clean frame unless its value can change: the clean or corrupted
//   record reaches it at or before its end (kv_stop), or, on a list of several chunks, a record
//   that reaches it before its end moves across a chunk boundary (the removal or insertion shifts
//   the positions between them by one; records that skip a pixel change nothing in it, and a
//   chunk of them merges as the identity), or its clean value is not finite (conservative);
// - one chunk of the variant's list per dispatch: pass 0 the chunk it resumes in, each later pass
//   the next chunk a pixel must walk again (entry_next; the chunks between come from the clean
//   frame's per-chunk results); between dispatches the slab holds the chunks merged so far and
//   variant_ended the pixels that ended; an entry writes its pixels once every one has ended or
//   at its list's last chunk (entry_next = FINISHED then skips it).
@compute @workgroup_size(TILE, ROWS)
fn variants(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    opaque_zero = bitcast<u32>(rc.background.w);  // blend.wgsl unfused
    let e = rc.first_entry + linear_wg(wg, nwg);
    if (e >= rc.n_entries) {
        return;
    }
    let entry = entries[e];
    let b = entry.variant;
    let v = entry.view;
    let tile = entry.tile;
    let prim = entry.prim;
    let tx = tile % rc.tiles_x;
    let ty = tile / rc.tiles_x;
    let row0 = lid.y * SPAN;
    let tile0 = vec2<u32>(tx * TILE, ty * TILE);
    var p = entry_pixels(tile0, lid.x, row0);
    let range = kv_ranges[v * rc.n_tiles + tile];
    let vi = v * rc.n_variants + b;
    // pass 0 walks the chunk the entry resumes in; each later pass the next chunk that one of its
    // pixels must walk again (entry_next); an entry that wrote its pixels leaves at once
    let k = rc.chunk_pass;
    if (li == 0u) {
        var status = 0u;
        if (k > 0u) {
            status = entry_next[e];
        }
        s_status = status;
    }
    let next = workgroupUniformLoad(&s_status);
    if (next == FINISHED) {
        return;  // uniform: written in an earlier pass
    }
    if (li == 0u) {
        atomicStore(&s_done, 0u);
        atomicStore(&s_changed[0], 0xffu);
        atomicStore(&s_changed[1], 0u);
        atomicStore(&s_changed[2], 0xffu);
        atomicStore(&s_changed[3], 0u);
        reset_active();
        let n = range.y - range.x;
        // the clean entry of the corrupted primitive, if this tile lists it
        let ck = clean_key(v, prim);
        let qpos = count_before(v, range.x, range.y, ck, prim);
        var removed = NONE;
        if (qpos < n && kv_isect[list_base(v) + range.x + qpos] == prim) {
            removed = qpos;
        }
        // the re-projected variant, if the binning pairs it with this tile (its rectangle covers the
        // tile and, under exact binning, its footprint reaches it: bin.wgsl's rule; an extra pair
        // that draws nothing would still move the chunk boundaries of a long list)
        let r = var_rect[vi];
        var insert = NONE;
        var paired = (r.x & 0xffffu) <= tx && tx < (r.y & 0xffffu) && (r.x >> 16u) <= ty && ty < (r.y >> 16u);
        if (paired && EXACT_BIN) {
            let cols = row_tiles(reach(var_xy[vi], var_conic[vi]), f32(ty * TILE), 0.0, r.x & 0xffffu, r.y & 0xffffu);
            paired = cols.x <= tx && tx < cols.y;
        }
        var insert_at = NONE;
        if (paired) {
            insert_at = count_before(v, range.x, range.y, bitcast<u32>(var_rgb[vi].w), prim);
            insert = insert_at;
            if (removed != NONE && removed < insert) {
                insert = insert - 1u;
            }
        }
        s_insert_at = insert_at;
        var nv = n;
        if (removed != NONE) { nv = nv - 1u; }
        if (insert != NONE) { nv = nv + 1u; }
        s_list = vec4<u32>(nv, insert, removed, u32(n > CHUNK_PAIRS || nv > CHUNK_PAIRS));
        // the clean positions the change shifts by one (down after a removal, up after an insertion)
        var lo = 0u;
        var end = 0u;
        var down = true;
        if (removed != NONE && (insert == NONE || insert_at > removed)) {
            lo = removed + 1u;
            end = select(insert_at, n, insert == NONE);
        } else if (insert != NONE) {
            lo = insert_at;
            end = select(removed, n, removed == NONE);
            down = false;
        }
        // those among them that cross a chunk boundary: jC (down) or jC - 1 (up)
        var cross = NONE;
        if (lo < end) {
            if (down) {
                cross = (lo + CHUNK_PAIRS - 1u) / CHUNK_PAIRS * CHUNK_PAIRS;
            } else {
                cross = (lo + CHUNK_PAIRS) / CHUNK_PAIRS * CHUNK_PAIRS - 1u;
            }
        }
        s_cross = vec2<u32>(cross, end);
        let a = min(removed, insert);
        var s = 0u;  // the walk resumes at the clean frame's last checkpoint at or before a
        if (a != NONE && n > 0u) {
            s = min(a / rc.ckpt_every, (n - 1u) / rc.ckpt_every) * rc.ckpt_every;
        }
        s_walk = vec2<u32>(a, s);
    }
    let list = workgroupUniformLoad(&s_list);
    let walk = workgroupUniformLoad(&s_walk);
    let nv = list.x;
    let insert = list.y;
    let removed = list.z;
    let multi = list.w != 0u;
    let a = walk.x;
    let s = walk.y;
    let cs = s / CHUNK_PAIRS;
    let c = select(next, cs, k == 0u);
    let n_chunks = max(1u, (nv + CHUNK_PAIRS - 1u) / CHUNK_PAIRS);
    let clean_chunks = max(1u, (range.y - range.x + CHUNK_PAIRS - 1u) / CHUNK_PAIRS);
    let insert_at = workgroupUniformLoad(&s_insert_at);
    let cross = workgroupUniformLoad(&s_cross);
    // Pixels the change cannot reach, copied from the clean frame (see above): a pixel's value
    // depends only on the records that do not skip it, in list order, grouped by chunk, up to its
    // end (kv_stop, a position in the clean list). On opaque surfaces most upsets of hidden
    // primitives then re-blend nothing.
    let o = prim_base(v) + prim;
    var copy_clean: array<vec4<bool>, QPI>;
    var limit: Stops;
    var walks: Stops;  // per pixel, bit min(j, 31) for each later chunk j whose records change for it
    var stops: Stops;
    let x_stop = min(tile0.x + lid.x, rc.width - 1u);
    for (var j = 0u; j < QPI; j = j + 1u) {
        var stop: vec4<u32>;
        var odd = vec4<bool>(false);
        for (var i = 0u; i < QUAD; i = i + 1u) {
            let y = min(tile0.y + row0 + QUAD * j + i, rc.height - 1u);
            let at = (v * rc.height + y) * rc.width + x_stop;
            stop[i] = kv_stop[at];
            if (cross.x < cross.y) {
                let px = bitcast<vec4<u32>>(clean_image[at]);
                odd[i] = any((px & vec4<u32>(0x7f800000u)) == vec4<u32>(0x7f800000u));
            }
        }
        let open = (stop & vec4<u32>(OPEN)) != vec4<u32>(0u);
        let alive = vec4<bool>(a != NONE) & within(vec4<u32>(a), stop);
        let old_hits = contributes(kv_xy[o], kv_conic[o], p.q[j]) & vec4<bool>(removed != NONE);
        let new_hits = contributes(var_xy[vi], var_conic[vi], p.q[j]) & vec4<bool>(insert != NONE);
        let new_reaches = new_hits & (within(vec4<u32>(insert_at), stop) | open);
        let old_reaches = old_hits & within(vec4<u32>(removed), stop);
        let reached = old_reaches | new_reaches;
        var moved = odd & vec4<bool>(cross.x < cross.y);
        var walk_bits = select(vec4<u32>(0u), vec4<u32>(chunk_bit(removed / CHUNK_PAIRS)), old_reaches)
            | select(vec4<u32>(0u), vec4<u32>(chunk_bit(insert / CHUNK_PAIRS)), new_reaches);
        if (cross.x < cross.y) {
            walk_bits = walk_bits | select(vec4<u32>(0u), vec4<u32>(0xffffffffu), odd);
        }
        for (var i = cross.x; i < cross.y; i = i + CHUNK_PAIRS) {
            let og = prim_base(v) + kv_isect[list_base(v) + range.x + i];
            let hit = contributes(kv_xy[og], kv_conic[og], p.q[j]) & within(vec4<u32>(i - 1u), stop);
            moved = moved | hit;
            // the record leaves one chunk for its neighbour: both change
            let after = (i + 1u) / CHUNK_PAIRS;
            walk_bits = walk_bits | select(vec4<u32>(0u), vec4<u32>(chunk_bit(after) | chunk_bit(after - 1u)), hit);
        }
        walks[j] = walk_bits;
        stops[j] = stop;
        copy_clean[j] = !p.q[j].done & !(reached | (alive & moved));
        // a pixel that never ends is done past the last record that can reach it: the clean
        // list's last (its position in the variant's list at most one further), or the new one
        let last_clean = (stop & vec4<u32>(~OPEN)) + 1u;
        let last_new = select(vec4<u32>(0u), vec4<u32>(insert + 1u), new_hits);
        limit[j] = select(vec4<u32>(NONE), max(last_clean, last_new), open);
        p.q[j].done = p.q[j].done | copy_clean[j];
    }
    var acc = p;
    var take: array<vec4<bool>, QPI>;  // pixels that take this chunk's result from the clean frame
    if (k > 0u) {
        acc = read_variant_state(e, li, lid.x, row0, p);
        for (var j = 0u; j < QPI; j = j + 1u) {
            take[j] = !acc.q[j].done & !must_walk(walks[j], stops[j], c);
            p.q[j].done = acc.q[j].done | take[j];
        }
    }
    count_if_done(&p);
    let live = live_box(&p, lid.x, row0);
    let origin = vec2<f32>(tile0);
    var start = c * CHUNK_PAIRS;
    if (k == 0u) {
        // the clean frame's state at s: the merged chunks before chunk cs, and chunk cs's own walk
        let slot0 = ckpt_base[v * rc.n_tiles + tile];
        if (cs > 0u) {
            acc = read_checkpoint(slot0 + cs * CHUNK_PAIRS / rc.ckpt_every - 1u, lid.x, row0, p);
        }
        if (s > cs * CHUNK_PAIRS) {
            p = read_checkpoint(slot0 + s / rc.ckpt_every - 1u, lid.x, row0, p);
        }
        start = s;
    }
    let insert_box = box_of(var_xy[vi], var_conic[vi], cut_of(var_conic[vi].w), origin);
    let w = Walk(v, range.x, insert, removed, var_xy[vi], var_conic[vi], var_rgb[vi], insert_box);
    var no_record = no_stops();
    var no_last = no_stops();
    walk_list(&p, li, lid.x, row0, start, min(nv, (c + 1u) * CHUNK_PAIRS), live, w, limit, &no_record, &no_last, 0u);
    if (multi) {
        let slot0 = chunk_base[v * rc.n_tiles + tile];
        if (k > 0u) {
            p = take_clean_chunk(p, take, slot0, c, clean_chunks, lid.x, row0);
        }
        merge_pixels(&acc, &p, c == 0u);
        // the later chunks no pixel must walk again: their clean results, merged here
        var j = c + 1u;
        loop {
            if (j >= n_chunks || all_pixels_finished(&acc, li)) {
                break;
            }
            if (li == 0u) {
                atomicStore(&s_need, 0u);
            }
            workgroupBarrier();
            var all_take: array<vec4<bool>, QPI>;
            var need = false;
            for (var q = 0u; q < QPI; q = q + 1u) {
                all_take[q] = !acc.q[q].done;
                need = need || any(!acc.q[q].done & must_walk(walks[q], stops[q], j));
            }
            if (need) {
                atomicStore(&s_need, 1u);
            }
            workgroupBarrier();
            if (li == 0u) {
                s_needed = atomicLoad(&s_need);
            }
            if (workgroupUniformLoad(&s_needed) != 0u) {
                break;
            }
            var ch = take_clean_chunk(restart(&acc), all_take, slot0, j, clean_chunks, lid.x, row0);
            merge_pixels(&acc, &ch, false);
            j = j + 1u;
        }
        p = acc;
        if (j < n_chunks && !all_pixels_finished(&p, li)) {
            write_variant_state(e, li, &p, lid.x, row0);
            if (li == 0u) {
                entry_next[e] = j;
            }
            return;
        }
    }
    let bg = rc.background.xyz;
    let x = tile0.x + lid.x;
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            let ly = row0 + QUAD * j + i;
            let y = tile0.y + ly;
            let clean_px = clean_image[(v * rc.height + min(y, rc.height - 1u)) * rc.width + min(x, rc.width - 1u)];
            var px = out_pixel(p.q[j], i, bg);
            if (copy_clean[j][i]) {
                px = clean_px;
            }
            slabs[e * TILE_PIXELS + ly * TILE + lid.x] = px;
            let same = all(bitcast<vec3<u32>>(px.xyz) == bitcast<vec3<u32>>(clean_px.xyz));
            if (x < rc.width && y < rc.height && !same) {
                atomicMin(&s_changed[0], lid.x);
                atomicMax(&s_changed[1], lid.x);
                atomicMin(&s_changed[2], ly);
                atomicMax(&s_changed[3], ly);
            }
        }
    }
    // the tile-local box of the pixels whose rgb bits differ from the clean frame's (EMPTY_BOX's
    // x0 > x1 where none): the metrics reduce only such tiles, and the neighbours whose SSIM
    // windows reach those pixels; the rest contribute exactly nothing
    workgroupBarrier();
    if (li == 0u) {
        slab_changed[e] = atomicLoad(&s_changed[0]) | (atomicLoad(&s_changed[1]) << 8u)
            | (atomicLoad(&s_changed[2]) << 16u) | (atomicLoad(&s_changed[3]) << 24u);
        entry_next[e] = FINISHED;
    }
}

// The checkpoint pass over a clean frame's listed tiles (entries: view and tile; render/
// incremental.py CleanViews), one chunk per dispatch like `variants`, with the same arithmetic: it
// keeps the pixels' state at every checkpoint position of the list and writes each pixel's end
// (where it stopped; the last position of the chunk whose merge ended it; NEVER) into kv_stop.
@compute @workgroup_size(TILE, ROWS)
fn checkpoints(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    opaque_zero = bitcast<u32>(rc.background.w);  // blend.wgsl unfused
    let e = rc.first_entry + linear_wg(wg, nwg);
    if (e >= rc.n_entries) {
        return;
    }
    let v = entries[e].view;
    let tile = entries[e].tile;
    let row0 = lid.y * SPAN;
    let tile0 = vec2<u32>(tile % rc.tiles_x, tile / rc.tiles_x) * TILE;
    var p = entry_pixels(tile0, lid.x, row0);
    let range = kv_ranges[v * rc.n_tiles + tile];
    if (li == 0u) {
        atomicStore(&s_done, 0u);
        reset_active();
        s_list = vec4<u32>(range.y - range.x, 0u, 0u, 0u);
    }
    let n = workgroupUniformLoad(&s_list).x;
    let c = rc.chunk_pass;
    let n_chunks = max(1u, (n + CHUNK_PAIRS - 1u) / CHUNK_PAIRS);
    if (c >= n_chunks) {
        return;  // uniform
    }
    var acc = p;
    if (c > 0u) {
        acc = read_variant_state(e, li, lid.x, row0, p);
        for (var j = 0u; j < QPI; j = j + 1u) {
            p.q[j].done = acc.q[j].done;
        }
    }
    var ended_before: array<vec4<bool>, QPI>;
    for (var j = 0u; j < QPI; j = j + 1u) {
        ended_before[j] = acc.q[j].done;
    }
    count_if_done(&p);
    let live = live_box(&p, lid.x, row0);
    let start = c * CHUNK_PAIRS;
    let hi = min(n, start + CHUNK_PAIRS);
    let slot0 = ckpt_base[v * rc.n_tiles + tile];
    var stops = no_stops();
    var last = Stops(vec4<u32>(0u), vec4<u32>(0u));
    let w = Walk(v, range.x, NONE, NONE, vec2<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), EMPTY_BOX);
    walk_list(&p, li, lid.x, row0, start, hi, live, w, no_stops(), &stops, &last, slot0);
    merge_pixels(&acc, &p, c == 0u);
    let x = tile0.x + lid.x;
    for (var j = 0u; j < QPI; j = j + 1u) {
        for (var i = 0u; i < QUAD; i = i + 1u) {
            let y = tile0.y + row0 + QUAD * j + i;
            let now = acc.q[j].done[i] && !ended_before[j][i];
            let open = !acc.q[j].done[i] && (c == 0u || last[j][i] != 0u);  // (1 + the last reaching record)
            if (x < rc.width && y < rc.height && (now || open)) {
                var end = OPEN | last[j][i];
                if (now) {
                    end = select(hi - 1u, stops[j][i], p.q[j].done[i] && stops[j][i] != NEVER);
                }
                kv_stop[(v * rc.height + y) * rc.width + x] = end;
            }
        }
    }
    if (c > 0u) {
        // the chunk's own result (t negated where it stopped), for variants that leave it as it was
        let slot = chunk_base[v * rc.n_tiles + tile] + c - 1u;
        for (var j = 0u; j < QPI; j = j + 1u) {
            let stopped = p.q[j].done & !ended_before[j];
            let t = select(p.q[j].T, -p.q[j].T, stopped);
            for (var i = 0u; i < QUAD; i = i + 1u) {
                chunk_states[slot_pixel(slot, lid.x, row0, j, i)] = vec4<f32>(p.q[j].r[i], p.q[j].g[i], p.q[j].b[i], t[i]);
            }
        }
    }
    if (c + 1u < n_chunks) {
        write_checkpoint(slot0 + (start + CHUNK_PAIRS) / rc.ckpt_every - 1u, &acc, lid.x, row0);
        write_variant_state(e, li, &acc, lid.x, row0);
    }
}
