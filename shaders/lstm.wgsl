// The LSTM cell update (Rust side: src/ops/lstm.rs), element by element. The gates'
// pre-activations z are [B, 4, M] (i, f, o, g for each window's M state elements, as one
// convolution over [4·C_h] output channels writes them); the kernel applies σ to i, f, o
// and tanh to g itself:
//   c' = f ⊙ c + i ⊙ g        h' = o ⊙ tanh(c')
// The backward, from ∂ℒ/∂h' and ∂ℒ/∂c' (the next step's, or zeros), writes ∂ℒ/∂z and
// ∂ℒ/∂c (both overwritten):
//   dc' = ∂ℒ/∂c' + ∂ℒ/∂h' ⊙ o ⊙ (1 − tanh²(c'))
//   di = dc' ⊙ g, df = dc' ⊙ c, do = ∂ℒ/∂h' ⊙ tanh(c'), dg = dc' ⊙ i, ∂ℒ/∂c = dc' ⊙ f
//   then through σ and tanh into ∂ℒ/∂z.

struct LstmParams {
    // B·M: state elements.
    n: u32,
    // M: state elements per window.
    m: u32,
    _pad0: u32,
    _pad1: u32,
}

const LSTM_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: LstmParams;

@group(0) @binding(1) var<storage, read> z: array<f32>;
@group(0) @binding(2) var<storage, read> c_prev: array<f32>;
@group(0) @binding(3) var<storage, read_write> c_out: array<f32>;
@group(0) @binding(4) var<storage, read_write> h_out: array<f32>;

// Index of gate q (0 i, 1 f, 2 o, 3 g) of state element k in z.
fn gate_at(k: u32, q: u32) -> u32 {
    return ((k / p.m) * 4u + q) * p.m + k % p.m;
}

@compute @workgroup_size(256)
fn lstm_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let k = flat_index(wg, nwg, li, LSTM_WG);
    if k >= p.n {
        return;
    }
    let i = sigmoid(z[gate_at(k, 0u)]);
    let f = sigmoid(z[gate_at(k, 1u)]);
    let o = sigmoid(z[gate_at(k, 2u)]);
    let g = tanh_stable(z[gate_at(k, 3u)]);
    let c = f * c_prev[k] + i * g;
    c_out[k] = c;
    h_out[k] = o * tanh_stable(c);
}

@group(0) @binding(3) var<storage, read> c_new: array<f32>;
@group(0) @binding(4) var<storage, read> d_h: array<f32>;
@group(0) @binding(5) var<storage, read> d_c_next: array<f32>;
@group(0) @binding(6) var<storage, read_write> d_z: array<f32>;
@group(0) @binding(7) var<storage, read_write> d_c: array<f32>;

@compute @workgroup_size(256)
fn lstm_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) li: u32) {
    let k = flat_index(wg, nwg, li, LSTM_WG);
    if k >= p.n {
        return;
    }
    let i = sigmoid(z[gate_at(k, 0u)]);
    let f = sigmoid(z[gate_at(k, 1u)]);
    let o = sigmoid(z[gate_at(k, 2u)]);
    let g = tanh_stable(z[gate_at(k, 3u)]);
    let tc = tanh_stable(c_new[k]);
    let dc = d_c_next[k] + d_h[k] * o * (1.0 - tc * tc);
    d_z[gate_at(k, 0u)] = dc * g * i * (1.0 - i);
    d_z[gate_at(k, 1u)] = dc * c_prev[k] * f * (1.0 - f);
    d_z[gate_at(k, 2u)] = d_h[k] * tc * o * (1.0 - o);
    d_z[gate_at(k, 3u)] = dc * i * (1.0 - g * g);
    d_c[k] = dc * f;
}
