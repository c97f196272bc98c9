// Gated dilated causal convolution (docs/model.md step 4; Rust side:
// src/model/block/gated_dcc/kernel.rs).
//
// The convolution runs as a GEMM over a causal unfolding of its input:
//   col[r, c, k, t] = x[r, c, t − d·k]   (0 when t − d·k < 0; r = b·N + n)
// so that G[r] = weight [C, C·K] · col[r] [C·K, T] with the docs/model.md weight layout
// [o, c, k] read as a [C, C·K] matrix. `outputs` keeps only the last steps of col
// (t ≥ T − outputs): the last block computes its convolution only where the head reads. The GEMMs are ops::matmul; this file holds the
// unfolding and the gate H = tanh(G_f) ⊙ σ(G_g), forward and backward.

struct UnfoldParams {
    rows: u32,
    channels: u32,
    kernel: u32,
    steps: u32,
    dilation: u32,
    accumulate: u32,
    outputs: u32,
    // Backward: x was a ReLU's output, and the gradient wanted is its input's: (x > 0)·dx.
    relu_input: u32,
}

const DCC_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> u: UnfoldParams;

@group(0) @binding(1) var<storage, read> ux: array<f32>;
@group(0) @binding(2) var<storage, read_write> ucol: array<f32>;

// One invocation per element of col.
@compute @workgroup_size(256)
fn unfold_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DCC_WG);
    if i >= u.rows * u.channels * u.kernel * u.outputs {
        return;
    }
    let t = u.steps - u.outputs + i % u.outputs;
    let rck = i / u.outputs;
    let k = rck % u.kernel;
    let rc = rck / u.kernel;
    let lag = u.dilation * k;
    var v = 0.0;
    if t >= lag {
        v = ux[rc * u.steps + t - lag];
    }
    ucol[i] = v;
}

// dx[r, c, t] (+)= Σ_k dcol[r, c, k, t + d·k] over the kept steps: a gather, one
// invocation per element of x. With relu_input, masked by x > 0 (binding 3, x).
@group(0) @binding(1) var<storage, read> udcol: array<f32>;
@group(0) @binding(2) var<storage, read_write> udx: array<f32>;
@group(0) @binding(3) var<storage, read> ufx: array<f32>;

@compute @workgroup_size(256)
fn unfold_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DCC_WG);
    if i >= u.rows * u.channels * u.steps {
        return;
    }
    let t = i % u.steps;
    let rc = i / u.steps;
    let first = u.steps - u.outputs;
    var s = 0.0;
    for (var k = 0u; k < u.kernel; k++) {
        let src = t + u.dilation * k;
        if src >= first && src < u.steps {
            s += udcol[(rc * u.kernel + k) * u.outputs + src - first];
        }
    }
    if u.relu_input != 0u && ufx[i] <= 0.0 {
        s = 0.0;
    }
    if u.accumulate != 0u {
        udx[i] = udx[i] + s;
    } else {
        udx[i] = s;
    }
}

// The same two maps four steps at a time, when the kept steps and T are multiples of 4:
// one vector store per invocation instead of four scalar ones (2-3x faster on lavapipe).
@group(0) @binding(2) var<storage, read_write> ucol4: array<vec4<f32>>;

fn ux_or_zero(rc: u32, t: u32, lag: u32) -> f32 {
    if t >= lag {
        return ux[rc * u.steps + t - lag];
    }
    return 0.0;
}

@compute @workgroup_size(256)
fn unfold_forward4(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DCC_WG);
    let quads = u.outputs / 4u;
    if i >= u.rows * u.channels * u.kernel * quads {
        return;
    }
    let t = u.steps - u.outputs + 4u * (i % quads);
    let rck = i / quads;
    let lag = u.dilation * (rck % u.kernel);
    let rc = rck / u.kernel;
    ucol4[i] = vec4<f32>(ux_or_zero(rc, t, lag), ux_or_zero(rc, t + 1u, lag),
                         ux_or_zero(rc, t + 2u, lag), ux_or_zero(rc, t + 3u, lag));
}

@group(0) @binding(2) var<storage, read_write> udx4: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> ufx4: array<vec4<f32>>;

fn dcol_at(rc: u32, k: u32, src: u32) -> f32 {
    let first = u.steps - u.outputs;
    if src >= first && src < u.steps {
        return udcol[(rc * u.kernel + k) * u.outputs + src - first];
    }
    return 0.0;
}

@compute @workgroup_size(256)
fn unfold_backward4(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                    @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DCC_WG);
    let quads = u.steps / 4u;
    if i >= u.rows * u.channels * quads {
        return;
    }
    let t = 4u * (i % quads);
    let rc = i / quads;
    var s = vec4<f32>(0.0);
    for (var k = 0u; k < u.kernel; k++) {
        let src = t + u.dilation * k;
        s += vec4<f32>(dcol_at(rc, k, src), dcol_at(rc, k, src + 1u), dcol_at(rc, k, src + 2u),
                       dcol_at(rc, k, src + 3u));
    }
    if u.relu_input != 0u {
        s = select(vec4<f32>(0.0), s, ufx4[i] > vec4<f32>(0.0));
    }
    if u.accumulate != 0u {
        s += udx4[i];
    }
    udx4[i] = s;
}

// H = tanh(f) ⊙ σ(g), elementwise over n values.
struct GateParams {
    n: u32,
    // gate_backward_stacked: elements per item (C·T) of f, g and dh.
    block: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> gp: GateParams;
@group(0) @binding(1) var<storage, read> gf: array<f32>;
@group(0) @binding(2) var<storage, read> gg: array<f32>;
@group(0) @binding(3) var<storage, read_write> gh: array<f32>;

@compute @workgroup_size(256)
fn gate_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DCC_WG);
    if i >= gp.n {
        return;
    }
    gh[i] = tanh_stable(gf[i]) * sigmoid(gg[i]);
}

// df = dh · σ(g) · (1 − tanh²f), dg = dh · tanh(f) · σ(g)(1 − σ(g)).
@group(0) @binding(1) var<storage, read> bf: array<f32>;
@group(0) @binding(2) var<storage, read> bg: array<f32>;
@group(0) @binding(3) var<storage, read> bdh: array<f32>;

// (df, dg) of element i.
fn gate_grads(i: u32) -> vec2<f32> {
    let th = tanh_stable(bf[i]);
    let sg = sigmoid(bg[i]);
    let d = bdh[i];
    return vec2<f32>(d * sg * (1.0 - th * th), d * th * sg * (1.0 - sg));
}

// Written stacked per item: [df; dg] as [2C, T] for each (b, n), so that the filter and
// gate convolutions' backward run as one product with twice the rows (gated_dcc/kernel.rs).
@group(0) @binding(4) var<storage, read_write> bdfg: array<f32>;

@compute @workgroup_size(256)
fn gate_backward_stacked(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                         @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DCC_WG);
    if i >= gp.n {
        return;
    }
    let d = gate_grads(i);
    let j = i + (i / gp.block) * gp.block;
    bdfg[j] = d.x;
    bdfg[j + gp.block] = d.y;
}
