// The head's input (docs/model.md "Head"; Rust side: src/ops/head.rs): the last time step
// of the last block, h[b, n·C + c] = Y[b, n, c, T − 1], and its backward scatter.

struct HeadParams {
    rows: u32,   // B·N·C
    steps: u32,  // T
    _pad0: u32,
    _pad1: u32,
}

const HEAD_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: HeadParams;

@group(0) @binding(1) var<storage, read> y: array<f32>;
@group(0) @binding(2) var<storage, read_write> h: array<f32>;

@compute @workgroup_size(256)
fn last_step_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                     @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, HEAD_WG);
    if i >= p.rows {
        return;
    }
    h[i] = y[i * p.steps + p.steps - 1u];
}

// dY[.., t] = dh at t = T − 1 and 0 elsewhere (the whole of dY is written).
@group(0) @binding(1) var<storage, read> dh: array<f32>;
@group(0) @binding(2) var<storage, read_write> dy: array<f32>;

@compute @workgroup_size(256)
fn last_step_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                      @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, HEAD_WG);
    if i >= p.rows * p.steps {
        return;
    }
    let row = i / p.steps;
    let t = i - row * p.steps;
    dy[i] = select(0.0, dh[row], t == p.steps - 1u);
}
