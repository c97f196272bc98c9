// The GRU state update (Rust side: src/ops/gru.rs): h' = u ⊙ h + (1 − u) ⊙ c, element by
// element, and its backward: du = (h − c) ⊙ dh', dc = (1 − u) ⊙ dh' (both overwritten),
// dh (+)= u ⊙ dh'.

struct GruParams {
    n: u32,
    accumulate: u32,
    _pad0: u32,
    _pad1: u32,
}

const GRU_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: GruParams;

@group(0) @binding(1) var<storage, read> u: array<f32>;
@group(0) @binding(2) var<storage, read> h: array<f32>;
@group(0) @binding(3) var<storage, read> c: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(256)
fn gru_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, GRU_WG);
    if i >= p.n {
        return;
    }
    out[i] = u[i] * h[i] + (1.0 - u[i]) * c[i];
}

@group(0) @binding(4) var<storage, read> d_out: array<f32>;
@group(0) @binding(5) var<storage, read_write> du: array<f32>;
@group(0) @binding(6) var<storage, read_write> dc: array<f32>;
@group(0) @binding(7) var<storage, read_write> dh: array<f32>;

@compute @workgroup_size(256)
fn gru_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, GRU_WG);
    if i >= p.n {
        return;
    }
    let g = d_out[i];
    du[i] = (h[i] - c[i]) * g;
    dc[i] = (1.0 - u[i]) * g;
    let prior = select(0.0, dh[i], p.accumulate == 1u);
    dh[i] = prior + u[i] * g;
}
