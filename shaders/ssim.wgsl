// #import common

// The SSIM deficit of 7x7 windows over a block of display-referred pixels (metrics.wgsl's
// tile_partials runs it over a tile and its 3-px halo). The file that imports it MUST declare
//   workgroup  m_blk: clean rgb at [i], faulted at [M_PLANE + i], i = hy * M_SPAN + hx
//   consts     M_SPAN (block cells a row), M_PLANE (cells a block)
//
// SSIM per channel: two-pass window statistics (means first, then centred sums: no cancellation
// in var = E[x^2] - E[x]^2; on hard cases this is closer to skimage-in-float64 than skimage run
// in float32 is). Each thread evaluates 4 vertically adjacent windows, sharing the cell reads
// (row sums for the means, one read per cell for the centred sums). The
// deficit written as 1 - A1*A2/(B1*B2) = (e1*B2 + A1*e2) / (B1*B2) with e1 = (ux - uy)^2 = B1 - A1
// and e2 = var(x - y) = B2 - A2. Every term is non-negative, so it is accurate, and identical
// windows give e1 = e2 = 0 exactly, i.e. SSIM exactly 1 whatever the compiler does with the
// division (no reliance on x / x == 1).

const M_C1: f32 = 0.0001;           // (0.01 * 1)^2
const M_C2: f32 = 0.0009;           // (0.03 * 1)^2

// Centred second moments of one window, per channel.
struct MAcc {
    sxx: vec3<f32>,
    syy: vec3<f32>,
    sdd: vec3<f32>,
};

fn m_acc(acc: MAcc, x: vec3<f32>, y: vec3<f32>, ux: vec3<f32>, uy: vec3<f32>) -> MAcc {
    let dx = x - ux;
    let dy = y - uy;
    let dd = dx - dy;
    return MAcc(acc.sxx + dx * dx, acc.syy + dy * dy, acc.sdd + dd * dd);
}

// SSIM deficit (1 - SSIM, mean over r,g,b) of one window from its means and centred sums.
fn m_deficit(ux: vec3<f32>, uy: vec3<f32>, acc: MAcc) -> f32 {
    let vx = acc.sxx / 48.0;    // sample covariance: NP / (NP - 1) with NP = 49
    let vy = acc.syy / 48.0;
    let e2 = acc.sdd / 48.0;    // = vx + vy - 2 vxy = B2 - A2
    let du = ux - uy;
    let e1 = du * du;           // = B1 - A1
    let a1 = 2.0 * ux * uy + M_C1;
    let b1 = ux * ux + uy * uy + M_C1;
    let b2 = vx + vy + M_C2;
    let q = (e1 * b2 + a1 * e2) / (b1 * b2);
    return (q.x + q.y + q.z) / 3.0;
}

// SSIM deficits of the 4 vertically consecutive windows whose top-left block cells are
// (wx, wy + w), w = 0..3. Two passes (means, then centred sums) over the 10 x 7 cells they
// cover; each cell is read once per pass and feeds every window that contains it.
fn m_ssim4(wx: u32, wy: u32) -> vec4<f32> {
    let z = vec3<f32>(0.0);
    var sx0 = z; var sx1 = z; var sx2 = z; var sx3 = z;
    var sy0 = z; var sy1 = z; var sy2 = z; var sy3 = z;
    for (var r = 0u; r < 10u; r++) {
        let row = (wy + r) * M_SPAN + wx;
        var rx = z;
        var ry = z;
        for (var i = 0u; i < 7u; i++) {
            rx += m_blk[row + i].xyz;
            ry += m_blk[M_PLANE + row + i].xyz;
        }
        if (r < 7u) { sx0 += rx; sy0 += ry; }
        if (r >= 1u && r < 8u) { sx1 += rx; sy1 += ry; }
        if (r >= 2u && r < 9u) { sx2 += rx; sy2 += ry; }
        if (r >= 3u) { sx3 += rx; sy3 += ry; }
    }
    let ux0 = sx0 / 49.0; let ux1 = sx1 / 49.0; let ux2 = sx2 / 49.0; let ux3 = sx3 / 49.0;
    let uy0 = sy0 / 49.0; let uy1 = sy1 / 49.0; let uy2 = sy2 / 49.0; let uy3 = sy3 / 49.0;
    var a0 = MAcc(z, z, z); var a1 = a0; var a2 = a0; var a3 = a0;
    for (var r = 0u; r < 10u; r++) {
        let row = (wy + r) * M_SPAN + wx;
        for (var i = 0u; i < 7u; i++) {
            let x = m_blk[row + i].xyz;
            let y = m_blk[M_PLANE + row + i].xyz;
            if (r < 7u) { a0 = m_acc(a0, x, y, ux0, uy0); }
            if (r >= 1u && r < 8u) { a1 = m_acc(a1, x, y, ux1, uy1); }
            if (r >= 2u && r < 9u) { a2 = m_acc(a2, x, y, ux2, uy2); }
            if (r >= 3u) { a3 = m_acc(a3, x, y, ux3, uy3); }
        }
    }
    return vec4<f32>(m_deficit(ux0, uy0, a0), m_deficit(ux1, uy1, a1),
                     m_deficit(ux2, uy2, a2), m_deficit(ux3, uy3, a3));
}
