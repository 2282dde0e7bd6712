// #import variants_walk

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
    first_view: u32,    // the kept view group bound (kv_isect_prims, kv_isect_box, kv_proj_xy, kv_proj_conic, kv_proj_rgb start there)
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
@group(0) @binding(13) var<storage, read> kv_isect_prims: array<u32>;
@group(0) @binding(14) var<storage, read> kv_proj_xy: array<vec2<f32>>;
@group(0) @binding(15) var<storage, read> kv_proj_conic: array<vec4<f32>>;
@group(0) @binding(16) var<storage, read> kv_proj_rgb: array<vec4<f32>>;     // w = depth
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
@group(0) @binding(26) var<storage, read_write> kv_stop_pos: array<u32>;
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
@group(0) @binding(23) var<storage, read> kv_isect_box: array<u32>;              // pixel box per kept pair

const NONE: u32 = 0xffffffffu;
const OPEN: u32 = 0x80000000u;

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
        if (qpos < n && kv_isect_prims[list_base(v) + range.x + qpos] == prim) {
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
    // end (kv_stop_pos, a position in the clean list). On opaque surfaces most upsets of hidden
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
            stop[i] = kv_stop_pos[at];
            if (cross.x < cross.y) {
                let px = bitcast<vec4<u32>>(clean_image[at]);
                odd[i] = any((px & vec4<u32>(0x7f800000u)) == vec4<u32>(0x7f800000u));
            }
        }
        let open = (stop & vec4<u32>(OPEN)) != vec4<u32>(0u);
        let alive = vec4<bool>(a != NONE) & within(vec4<u32>(a), stop);
        let old_hits = contributes(kv_proj_xy[o], kv_proj_conic[o], p.q[j]) & vec4<bool>(removed != NONE);
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
            let og = prim_base(v) + kv_isect_prims[list_base(v) + range.x + i];
            let hit = contributes(kv_proj_xy[og], kv_proj_conic[og], p.q[j]) & within(vec4<u32>(i - 1u), stop);
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
// (where it stopped; the last position of the chunk whose merge ended it; NEVER) into kv_stop_pos.
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
                kv_stop_pos[(v * rc.height + y) * rc.width + x] = end;
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
