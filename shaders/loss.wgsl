// The training loss of MODEL.md eq. 39 without the weight-decay term (the optimiser adds
// 2λW to the weight gradients; Rust side: src/ops/loss.rs):
//   ℒ = (1/B) Σ_b Σ_m w_m (ŷ[b, m] − y[b, m])²,  w_m = 1 for m < 3 (position), P otherwise.

struct LossParams {
    batch: u32,
    outputs: u32,
    penalty: f32,
    _pad: u32,
}

const LOSS_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: LossParams;

fn weight_of(m: u32) -> f32 {
    return select(p.penalty, 1.0, m < 3u);
}

@group(0) @binding(1) var<storage, read> pred: array<f32>;
@group(0) @binding(2) var<storage, read> truth: array<f32>;
@group(0) @binding(3) var<storage, read_write> loss: array<f32>;

var<workgroup> partial: array<f32, LOSS_WG>;

// One workgroup: a strided sum per invocation, then a tree reduction into loss[0].
@compute @workgroup_size(256)
fn loss_forward(@builtin(local_invocation_index) li: u32) {
    var s = 0.0;
    for (var i = li; i < p.batch * p.outputs; i += LOSS_WG) {
        let e = pred[i] - truth[i];
        s += weight_of(i % p.outputs) * e * e;
    }
    partial[li] = s;
    workgroupBarrier();
    for (var half = LOSS_WG / 2u; half > 0u; half /= 2u) {
        if li < half {
            partial[li] += partial[li + half];
        }
        workgroupBarrier();
    }
    if li == 0u {
        loss[0] = partial[0] / f32(p.batch);
    }
}

// dŷ = (2/B) w_m (ŷ − y).
@group(0) @binding(1) var<storage, read> bpred: array<f32>;
@group(0) @binding(2) var<storage, read> btruth: array<f32>;
@group(0) @binding(3) var<storage, read_write> dpred: array<f32>;

@compute @workgroup_size(256)
fn loss_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, LOSS_WG);
    if i >= p.batch * p.outputs {
        return;
    }
    dpred[i] = 2.0 / f32(p.batch) * weight_of(i % p.outputs) * (bpred[i] - btruth[i]);
}
