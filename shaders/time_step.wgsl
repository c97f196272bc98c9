// One time step of a [rows, steps] tensor (Rust side: src/ops/time_step.rs): the gather
// h[r] = y[r, step] that feeds a recurrent cell its input at step t, and its backward.
// For x [B, N, F, T], rows = B·N·F and h is x_t [B, N, F].

struct TimeStepParams {
    rows: u32,
    steps: u32,
    step: u32,
    accumulate: u32,
}

const TIME_STEP_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: TimeStepParams;

@group(0) @binding(1) var<storage, read> y: array<f32>;
@group(0) @binding(2) var<storage, read_write> h: array<f32>;

@compute @workgroup_size(256)
fn time_step_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                     @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, TIME_STEP_WG);
    if i >= p.rows {
        return;
    }
    h[i] = y[i * p.steps + p.step];
}

// Overwrite: dY[r, t] = dh[r] at t = step and 0 elsewhere (the whole of dY is written;
// one invocation per element). Add: dY[r, step] += dh[r] (one invocation per row; the
// other steps are left as they are).
@group(0) @binding(1) var<storage, read> dh: array<f32>;
@group(0) @binding(2) var<storage, read_write> dy: array<f32>;

@compute @workgroup_size(256)
fn time_step_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                      @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, TIME_STEP_WG);
    if p.accumulate == 1u {
        if i >= p.rows {
            return;
        }
        let at = i * p.steps + p.step;
        dy[at] = dy[at] + dh[i];
        return;
    }
    if i >= p.rows * p.steps {
        return;
    }
    let row = i / p.steps;
    let t = i - row * p.steps;
    dy[i] = select(0.0, dh[row], t == p.step);
}
