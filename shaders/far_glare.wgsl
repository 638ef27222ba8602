// Stage 4, full-field stray light (issue 46): the CIE 146:2002 veil of
// every pixel onto every other at their angle, out to 90°, on a coarse
// angular grid; the twin of gazelight_vision::far_glare::FarField, step by
// step (its module docs and docs/perception.md, "Energy bookkeeping", give
// the split: the window kernel K holds CIE 146 tapered by t(θ), the far
// field tail = CIE 146·(1 − t)·cos θ for every source and near = CIE 146·
// t·h·cos θ for the (1 − w) share of a source outside the window).
//
// The host builds, from the CPU FarField of the same geometry, one table
// (`tables`, vec4<u32>, floats as their bits): per block its pixel's solid
// angle, its grid cell and bilinear fractions; per grid cell the blocks
// that splat into it (a gather: WGSL has no float atomics); per display
// column and row the block columns/rows and fractions of the bilinear
// spread back. The kernels' spectra (tail, near; real: the kernels are
// even) are transformed once, at setup, by gazelight_gpu::fft. Per frame:
// 1. `block_sums` (before glare.wgsl's blend changes the frame): per block
//    the sum of its pixels' light L and of w·L, w the glare window's
//    source weight (glare_window.wgsl; 0 when no window is placed);
// 2. `splat`: per grid cell, Σ over its blocks of the bilinear weight ×
//    (L·Ω, max(L − w·L, 0)·Ω); plane c (colour) holds A_c + i·B_c;
// 3. forward FFT (host);
// 4. `multiply`: Y(k) = Z(k)·(T + N)/2 + conj(Z(−k))·(T − N)/2 = F[A]·T +
//    i·F[B]·N, each thread a pair (k, −k) in place;
// 5. inverse FFT (host; with its 1/n²): A ∗ tail + i·B ∗ near;
// 6. `read_blocks`: per block, the bilinear four of re + im, ≥ 0;
// 7. `blend` (after glare.wgsl's blend): the block veils bilinear to every
//    pixel (along x, then y, as the CPU); inside the glare's output region
//    the pixel's own light was already kept by glare.wgsl, outside it is
//    kept here: keep0·L.

struct FarParams {
    // Frame size, pixels; block size, pixels; blocks per row and column.
    width: u32,
    height: u32,
    block_px: u32,
    blocks_w: u32,
    blocks_h: u32,
    // Grid cells per side (the FFT size).
    n: u32,
    // Whether glare.wgsl placed its window this frame (its uniforms hold it).
    placed: u32,
    // Table sections (vec4 index): cells, their blocks, columns, rows.
    cells_at: u32,
    entries_at: u32,
    cols_at: u32,
    rows_at: u32,
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> params: FarParams;
@group(0) @binding(1) var<uniform> glare: GlareParams;
@group(0) @binding(2) var<storage, read_write> work: array<vec4<f32>>;
// Per block: 3 vec4: Σ L, Σ w·L, the veil at its centre.
@group(0) @binding(3) var<storage, read_write> blocks: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> tables: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read_write> data: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read> spectrum: array<vec2<f32>>;

@compute @workgroup_size(8, 8, 1)
fn block_sums(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.blocks_w || gid.y >= params.blocks_h {
        return;
    }
    let b = params.block_px;
    let x0 = gid.x * b;
    let y0 = gid.y * b;
    let x1 = min(x0 + b, params.width);
    let y1 = min(y0 + b, params.height);
    var s = vec3<f32>(0.0);
    var ws = vec3<f32>(0.0);
    for (var y = y0; y < y1; y++) {
        for (var x = x0; x < x1; x++) {
            let p = work[y * params.width + x].xyz;
            s += p;
            if params.placed != 0u {
                ws += p * window_weight(glare, i32(x), i32(y));
            }
        }
    }
    let k = 3u * (gid.y * params.blocks_w + gid.x);
    blocks[k] = vec4<f32>(s, 0.0);
    blocks[k + 1u] = vec4<f32>(ws, 0.0);
}

@compute @workgroup_size(8, 8, 1)
fn splat(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.n;
    if gid.x >= n || gid.y >= n {
        return;
    }
    let cell = gid.y * n + gid.x;
    let range = tables[params.cells_at + cell];
    var a = vec3<f32>(0.0);
    var bb = vec3<f32>(0.0);
    for (var e = range.x; e < range.x + range.y; e++) {
        let entry = tables[params.entries_at + e];
        let blk = entry.x;
        let wgt = bitcast<f32>(entry.y);
        let om = bitcast<f32>(tables[blk].x);
        let s = blocks[3u * blk].xyz;
        let ws = blocks[3u * blk + 1u].xyz;
        a += s * om * wgt;
        bb += max(s - ws, vec3<f32>(0.0)) * om * wgt;
    }
    let plane = n * n;
    data[cell] = vec2<f32>(a.x, bb.x);
    data[plane + cell] = vec2<f32>(a.y, bb.y);
    data[2u * plane + cell] = vec2<f32>(a.z, bb.z);
}

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

fn conj(a: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x, -a.y);
}

@compute @workgroup_size(64, 1, 1)
fn multiply(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let n = params.n;
    let plane = n * n;
    let k = gid.x + gid.y * groups.x * 64u;
    if k >= 3u * plane {
        return;
    }
    let c = k / plane;
    let i = k % plane;
    let u = i % n;
    let v = i / n;
    let m = ((n - v) % n) * n + (n - u) % n;
    // The partner with the lower index does both.
    if m < i {
        return;
    }
    let t = spectrum[i].x;
    let q = spectrum[plane + i].x;
    let pp = vec2<f32>(0.5 * (t + q), 0.0);
    let mm = vec2<f32>(0.5 * (t - q), 0.0);
    let z = data[c * plane + i];
    let zm = data[c * plane + m];
    data[c * plane + i] = cmul(z, pp) + cmul(conj(zm), mm);
    if m != i {
        // T and N are even: their values at −k are those at k.
        data[c * plane + m] = cmul(zm, pp) + cmul(conj(z), mm);
    }
}

fn out_at(cell: u32) -> vec3<f32> {
    let plane = params.n * params.n;
    let r = data[cell];
    let g = data[plane + cell];
    let b = data[2u * plane + cell];
    return vec3<f32>(r.x + r.y, g.x + g.y, b.x + b.y);
}

@compute @workgroup_size(8, 8, 1)
fn read_blocks(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.blocks_w || gid.y >= params.blocks_h {
        return;
    }
    let blk = gid.y * params.blocks_w + gid.x;
    let info = tables[blk];
    let fx = bitcast<f32>(info.y);
    let fy = bitcast<f32>(info.z);
    let c = info.w;
    let n = params.n;
    var acc = out_at(c) * ((1.0 - fx) * (1.0 - fy));
    acc += out_at(c + 1u) * (fx * (1.0 - fy));
    acc += out_at(c + n) * ((1.0 - fx) * fy);
    acc += out_at(c + n + 1u) * (fx * fy);
    blocks[3u * blk + 2u] = vec4<f32>(max(acc, vec3<f32>(0.0)), 0.0);
}

fn veil_at(j: u32, i: u32) -> vec3<f32> {
    return blocks[3u * (j * params.blocks_w + i) + 2u].xyz;
}

@compute @workgroup_size(8, 8, 1)
fn blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let col = tables[params.cols_at + gid.x];
    let row = tables[params.rows_at + gid.y];
    let i0 = col.x;
    let i1 = min(i0 + 1u, params.blocks_w - 1u);
    let fx = bitcast<f32>(col.y);
    let fy = bitcast<f32>(row.z);
    // Along x on the two block rows, then along y (the CPU's order).
    let a0 = veil_at(row.x, i0);
    let lo = a0 + (veil_at(row.x, i1) - a0) * fx;
    let a1 = veil_at(row.y, i0);
    let hi = a1 + (veil_at(row.y, i1) - a1) * fx;
    let v = lo + (hi - lo) * fy;
    let f = gid.y * params.width + gid.x;
    let old = work[f];
    let x = i32(gid.x);
    let y = i32(gid.y);
    var keep = glare.keep0;
    if params.placed != 0u && x >= glare.x0 && x < glare.x1 && y >= glare.y0 && y < glare.y1 {
        keep = 1.0;
    }
    // w: the no-data flag of pooling.wgsl's import_scene, kept.
    work[f] = vec4<f32>(old.xyz * keep + v, old.w);
}
