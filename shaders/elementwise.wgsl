// Elementwise ops, forward and backward side by side (Rust side: src/ops/elementwise.rs).
//
// Unary kernels read `in0` and write `out`; binary and backward kernels read `in0` and
// `in1`. When `accumulate` is 1 the result is added to `out` (gradient accumulation),
// otherwise it overwrites it.

struct EwParams {
    n: u32,
    accumulate: u32,
    _pad0: u32,
    _pad1: u32,
}

const EW_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: EwParams;
@group(0) @binding(1) var<storage, read> in0: array<f32>;
@group(0) @binding(2) var<storage, read> in1: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

fn put(i: u32, v: f32) {
    if p.accumulate != 0u {
        out[i] = out[i] + v;
    } else {
        out[i] = v;
    }
}

// ---- forward ---------------------------------------------------------------------------

@compute @workgroup_size(256)
fn relu_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, relu(in0[i])); }
}

@compute @workgroup_size(256)
fn sigmoid_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, sigmoid(in0[i])); }
}

@compute @workgroup_size(256)
fn tanh_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, tanh_stable(in0[i])); }
}

@compute @workgroup_size(256)
fn add_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, in0[i] + in1[i]); }
}

@compute @workgroup_size(256)
fn mul_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, in0[i] * in1[i]); }
}

// ---- backward --------------------------------------------------------------------------
// in0: what the derivative needs (x for relu, y for sigmoid/tanh, the other factor for
// mul), in1: the upstream gradient dy.

@compute @workgroup_size(256)
fn relu_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, select(0.0, in1[i], in0[i] > 0.0)); }
}

@compute @workgroup_size(256)
fn sigmoid_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                    @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n {
        let y = in0[i];
        put(i, in1[i] * y * (1.0 - y));
    }
}

@compute @workgroup_size(256)
fn tanh_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n {
        let y = in0[i];
        put(i, in1[i] * (1.0 - y * y));
    }
}

// d(a + b)/da = 1: passes dy (in0) through to either operand's gradient.
@compute @workgroup_size(256)
fn add_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, in0[i]); }
}

// d(a * b)/da = b: in0 is the other factor, in1 is dy.
@compute @workgroup_size(256)
fn mul_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, EW_WG);
    if i < p.n { put(i, in0[i] * in1[i]); }
}
