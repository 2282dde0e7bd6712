// #import composite_lanes

// The single-upset variants' walk over a tile's list (variants.wgsl's entry points `variants` and
// `checkpoints` run it): locating the corrupted primitive's clean entry and its re-projected
// record in list order, staging the entries a round blends, the per-chunk walk with the change
// merged in at its depth, the clean frame's checkpoints and chunk results read and written, and
// the chunk bookkeeping. The file that imports it MUST declare (variants.wgsl does):
//   the uniform  rc: Recomp, with prim_base(v) and list_base(v) (a view's clean records and list)
//   storage      kv_ranges, kv_isect_prims, kv_proj_xy, kv_proj_conic, kv_proj_rgb, kv_isect_box, kv_stop_pos, ckpt_base,
//                ckpt_states, chunk_base, chunk_states, slabs, variant_ended, entry_next
//   consts       NONE, OPEN (kv_stop_pos's never-ending flag), FINISHED
// Whether clean list position x is at or before the pixels' ends (kv_stop_pos, above): for a pixel
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
    return bitcast<u32>(kv_proj_rgb[prim_base(v) + g].w);
}

// number of list entries ordered before (key, idx)
fn count_before(v: u32, start: u32, end: u32, key: u32, idx: u32) -> u32 {
    var lo = start;
    var hi = end;
    let base = list_base(v);
    while (lo < hi) {
        let mid = (lo + hi) >> 1u;
        let g = kv_isect_prims[base + mid];
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

// The list a walk reads: view v's clean tile list (starting at `first` in kv_isect_prims) with clean
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
                bx = kv_isect_box[list_base(w.v) + w.first + clean_pos(min(i, hi - 1u), w.insert, w.removed)];
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
                    let og = prim_base(w.v) + kv_isect_prims[at];  // its box: the clean frame's, for this very pair
                    stage_boxed(slot, kv_proj_xy[og], kv_proj_conic[og], kv_proj_rgb[og], kv_isect_box[at]);
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
//   record reaches it at or before its end (kv_stop_pos), or, on a list of several chunks, a record
//   that reaches it before its end moves across a chunk boundary (the removal or insertion shifts
//   the positions between them by one; records that skip a pixel change nothing in it, and a
//   chunk of them merges as the identity), or its clean value is not finite (conservative);
// - one chunk of the variant's list per dispatch: pass 0 the chunk it resumes in, each later pass
//   the next chunk a pixel must walk again (entry_next; the chunks between come from the clean
//   frame's per-chunk results); between dispatches the slab holds the chunks merged so far and
//   variant_ended the pixels that ended; an entry writes its pixels once every one has ended or
//   at its list's last chunk (entry_next = FINISHED then skips it).
