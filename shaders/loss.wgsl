// The training loss of docs/model.md eq. 39 without the weight-decay term (the optimiser adds
// 2λW to the weight gradients; Rust side: src/ops/loss.rs):
//   ℒ = (1/B) Σ_b Σ_m w_m (ŷ[b, m] − y[b, m])²,  w_m = 1 for m < 3 (position), P otherwise.
// With group = M > 1 (docs/model.md "Refinement") the batch holds G = B/M ensembles of M
// consecutive windows and each adds the loss of its mean prediction:
//   ℒ = (1/G) Σ_g [ (1/M) Σ_k ℓ(ŷ_gk, y_gk) + ℓ(mean_k ŷ_gk, mean_k y_gk) ]
//     = (1/B) [ Σ_b Σ_m w_m e[b, m]² + M Σ_g Σ_m w_m ē[g, m]² ],  e = ŷ − y, ē = mean_k e_gk.
// group = 1 is the plain loss (no ensemble term).

struct LossParams {
    batch: u32,
    outputs: u32,
    penalty: f32,
    group: u32,
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

// ē[g, m] of the forward's bindings.
fn group_mean_error(g: u32, m: u32) -> f32 {
    var s = 0.0;
    for (var k = 0u; k < p.group; k++) {
        let i = (g * p.group + k) * p.outputs + m;
        s += pred[i] - truth[i];
    }
    return s / f32(p.group);
}

// One workgroup: a strided sum per invocation (per-window terms, then with group > 1 the
// ensemble terms, one (g, m) per iteration), then a tree reduction into loss[0].
@compute @workgroup_size(256)
fn loss_forward(@builtin(local_invocation_index) li: u32) {
    var s = 0.0;
    for (var i = li; i < p.batch * p.outputs; i += LOSS_WG) {
        let e = pred[i] - truth[i];
        s += weight_of(i % p.outputs) * e * e;
    }
    if p.group > 1u {
        let pairs = (p.batch / p.group) * p.outputs;
        for (var i = li; i < pairs; i += LOSS_WG) {
            let m = i % p.outputs;
            let e = group_mean_error(i / p.outputs, m);
            s += f32(p.group) * weight_of(m) * e * e;
        }
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

// dŷ[b, m] = (2/B) w_m (e[b, m] + ē[b / M, m]) (the ē term only with group > 1; each
// invocation recomputes its ensemble's mean).
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
    let m = i % p.outputs;
    var e = bpred[i] - btruth[i];
    if p.group > 1u {
        let first = (i / p.outputs / p.group) * p.group;
        var s = 0.0;
        for (var k = 0u; k < p.group; k++) {
            let j = (first + k) * p.outputs + m;
            s += bpred[j] - btruth[j];
        }
        e += s / f32(p.group);
    }
    dpred[i] = 2.0 / f32(p.batch) * weight_of(m) * e;
}
