// Adam (docs/model.md: β1 0.9, β2 0.999, ε 1e-8) with the L2 weight decay of eq. 39 folded
// into the gradient, one tensor per dispatch, in place (Rust side: src/ops/adam.rs):
//   g' = g + 2·decay·w,  m = β1 m + (1 − β1) g',  v = β2 v + (1 − β2) g'²,
//   w −= lr · (m / bc1) / (sqrt(v / bc2) + ε).
// lr and the bias corrections bc1 = 1 − β1^t, bc2 = 1 − β2^t change every step and are
// shared by every tensor, so they live in a small storage tensor written by the host:
// hyper = [lr, bc1, bc2, 0]. The uniform block holds what is fixed per tensor.

struct AdamParams {
    numel: u32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    decay: f32,
    // 1 − β1 and 1 − β2 rounded from f64 on the host (1 − f32(0.999) is off by 1e-5).
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    _pad: u32,
}

const ADAM_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: AdamParams;
@group(0) @binding(1) var<storage, read_write> weight: array<f32>;
@group(0) @binding(2) var<storage, read> grad: array<f32>;
@group(0) @binding(3) var<storage, read_write> moment1: array<f32>;
@group(0) @binding(4) var<storage, read_write> moment2: array<f32>;
@group(0) @binding(5) var<storage, read> hyper: array<f32>;

@compute @workgroup_size(256)
fn adam_step(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, ADAM_WG);
    if i >= p.numel {
        return;
    }
    let w = weight[i];
    let g = grad[i] + 2.0 * p.decay * w;
    let m = p.beta1 * moment1[i] + p.one_minus_beta1 * g;
    let v = p.beta2 * moment2[i] + p.one_minus_beta2 * g * g;
    moment1[i] = m;
    moment2[i] = v;
    let lr = hyper[0];
    let m_hat = m / hyper[1];
    let v_hat = v / hyper[2];
    weight[i] = w - lr * m_hat / (sqrt(v_hat) + p.eps);
}
