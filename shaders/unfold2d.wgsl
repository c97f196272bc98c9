// The 2-D unfolding (im2col) of a "same"-padded k×k convolution (Rust side:
// src/ops/unfold2d.rs). The image is [B, C, H, W]; col is [B, C·k·k, H·W] with
//   col[b, (c, ky, kx), (y, x)] = img[b, c, y + ky − k/2, x + kx − k/2]   (0 outside),
// so that a convolution is weight [C_out, C·k·k] · col[b]. The backward folds col's
// gradient back onto the image (a gather: every image element sums the k·k entries that
// read it), overwriting or adding.

struct Unfold2dParams {
    batch: u32,
    channels: u32,
    height: u32,
    width: u32,
    kernel: u32,
    accumulate: u32,
    _pad0: u32,
    _pad1: u32,
}

const UNFOLD2D_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: Unfold2dParams;

@group(0) @binding(1) var<storage, read> img: array<f32>;
@group(0) @binding(2) var<storage, read_write> col: array<f32>;

// One thread per element of col.
@compute @workgroup_size(256)
fn unfold2d_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                    @builtin(local_invocation_index) li: u32) {
    let id = flat_index(wg, nwg, li, UNFOLD2D_WG);
    let hw = p.height * p.width;
    let kk = p.kernel * p.kernel;
    if id >= p.batch * p.channels * kk * hw {
        return;
    }
    let pos = id % hw;
    let row = (id / hw) % (p.channels * kk);
    let b = id / (hw * p.channels * kk);
    let c = row / kk;
    let ky = (row % kk) / p.kernel;
    let kx = row % p.kernel;
    let half = i32(p.kernel / 2u);
    let y = i32(pos / p.width) + i32(ky) - half;
    let x = i32(pos % p.width) + i32(kx) - half;
    var v = 0.0;
    if y >= 0 && y < i32(p.height) && x >= 0 && x < i32(p.width) {
        v = img[((b * p.channels + c) * p.height + u32(y)) * p.width + u32(x)];
    }
    col[id] = v;
}

@group(0) @binding(1) var<storage, read> d_col: array<f32>;
@group(0) @binding(2) var<storage, read_write> d_img: array<f32>;

// One thread per image element: the sum over the k·k col entries that read it.
@compute @workgroup_size(256)
fn unfold2d_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                     @builtin(local_invocation_index) li: u32) {
    let id = flat_index(wg, nwg, li, UNFOLD2D_WG);
    let hw = p.height * p.width;
    if id >= p.batch * p.channels * hw {
        return;
    }
    let x = i32(id % p.width);
    let y = i32((id / p.width) % p.height);
    let bc = id / hw;
    let kk = p.kernel * p.kernel;
    let half = i32(p.kernel / 2u);
    var s = 0.0;
    for (var ky = 0u; ky < p.kernel; ky++) {
        for (var kx = 0u; kx < p.kernel; kx++) {
            // The output position that read (y, x) through tap (ky, kx).
            let oy = y - i32(ky) + half;
            let ox = x - i32(kx) + half;
            if oy >= 0 && oy < i32(p.height) && ox >= 0 && ox < i32(p.width) {
                s += d_col[(bc * kk + ky * p.kernel + kx) * hw + u32(oy) * p.width + u32(ox)];
            }
        }
    }
    d_img[id] = select(0.0, d_img[id], p.accumulate == 1u) + s;
}
