//! The parameter table of docs/model.md: names, shapes, initialisation, weight decay, and the
//! fixed graph basis that θ combines into Ψ.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::config::{Family, ModelConfig, Variant};
use super::recurrent;
use crate::graph::Graph;

/// How a parameter starts (docs/model.md "Initialisation").
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Init {
    /// He uniform U(−√(6/fan_in), √(6/fan_in)).
    HeUniform {
        /// Length of the axis the weight is contracted over.
        fan_in: usize,
    },
    /// All zeros (biases, `be`, `bs`, `ln.beta`).
    Zeros,
    /// All ones (`ln.gamma`, `gwc.theta`).
    Ones,
}

/// One entry of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSpec {
    /// The docs/model.md name, e.g. `blocks.0.tat.U1`.
    pub name: String,
    /// Its row-major shape, e.g. `[C_in, N]`.
    pub shape: Vec<usize>,
    /// How it starts.
    pub init: Init,
    /// Counted in the λ‖W‖² term of the loss (weights only).
    pub decay: bool,
}

impl ParamSpec {
    /// Number of scalars: the product of the shape.
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }
}

fn spec(name: String, shape: &[usize], init: Init, decay: bool) -> ParamSpec {
    ParamSpec {
        name,
        shape: shape.to_vec(),
        init,
        decay,
    }
}

fn weight(name: String, shape: &[usize], fan_in: usize) -> ParamSpec {
    spec(name, shape, Init::HeUniform { fan_in }, true)
}

fn zeros(name: String, shape: &[usize]) -> ParamSpec {
    spec(name, shape, Init::Zeros, false)
}

/// The most parameters a model may have: 2^30 f32 values, 4 GiB.
pub const MAX_PARAMETERS: usize = 1 << 30;

/// Checks that `config` (already validated field by field) has at most
/// [`MAX_PARAMETERS`] parameters, counted from its shapes with checked arithmetic before
/// anything is allocated: a T×T attention or a C×C mix grows fast.
pub fn check_parameter_count(config: &ModelConfig) -> Result<(), String> {
    let count = param_specs(config).iter().try_fold(0usize, |sum, s| {
        let n = s.shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))?;
        sum.checked_add(n)
    });
    match count {
        Some(n) if n <= MAX_PARAMETERS => Ok(()),
        n => Err(format!(
            "model config: {} parameters (window = {}, channels = {}, nodes = {}, hidden = {}) \
             is beyond the {MAX_PARAMETERS} (4 GiB of f32) this engine allocates",
            n.map_or("more than 2^64".to_string(), |n| n.to_string()),
            config.window,
            config.channels,
            config.nodes,
            config.hidden
        )),
    }
}

/// Every parameter of `config`, in the canonical order (blocks in order, then the head;
/// for a dense baseline, its layers in order, the head last; for a recurrent baseline,
/// the gates r, u, c, EAT-GCN's attention over time, then the head).
pub fn param_specs(config: &ModelConfig) -> Vec<ParamSpec> {
    if config.variant.family() == Family::Recurrent {
        // Per gate (r, u, c) and graph support k: input and state weights [F, H] and
        // [H, H]; then the gate's bias [H]. EAT-GCN's attention over time: Wa [N·H, A],
        // ba [A], v [A] (A = H). Then the head on the state or context [O, N·H].
        let (f, h) = (config.features, config.hidden);
        let terms = recurrent::support_count(config);
        let mut out: Vec<ParamSpec> = Vec::new();
        for g in recurrent::GATES {
            for kind in ["wx", "wh"] {
                let fan_in = if kind == "wx" { f } else { h };
                for k in 0..terms {
                    let name = recurrent::weight_name(g, kind, k, terms);
                    out.push(weight(name, &[fan_in, h], fan_in));
                }
            }
            out.push(zeros(format!("cell.{g}.bias"), &[h]));
        }
        let nh = config.nodes * h;
        if recurrent::attends_over_time(config.variant) {
            out.push(weight("attn.W".into(), &[nh, h], nh));
            out.push(zeros("attn.b".into(), &[h]));
            out.push(weight("attn.v".into(), &[h], h));
        }
        out.push(weight("head.weight".into(), &[config.outputs, nh], nh));
        out.push(zeros("head.bias".into(), &[config.outputs]));
        return out;
    }
    if config.variant.family() == Family::ConvRecurrent {
        // ConvLSTM: the gates' k×k convolutions of x_t (1 channel) and h (C channels) into
        // 4C channels (i, f, o, g), their bias, then the head on the last state [O, C·N·F].
        let (c, kk) = (config.channels, config.kernel * config.kernel);
        let state = c * config.nodes * config.features;
        return vec![
            weight("cell.wx".into(), &[4 * c, kk], kk),
            weight("cell.wh".into(), &[4 * c, c * kk], c * kk),
            zeros("cell.bias".into(), &[4 * c]),
            weight("head.weight".into(), &[config.outputs, state], state),
            zeros("head.bias".into(), &[config.outputs]),
        ];
    }
    if let Some(arch) = super::dense::Architecture::of(config) {
        // Layer by layer: He-uniform weights [outputs, inputs] with weight decay, zero biases.
        return arch
            .layers
            .iter()
            .flat_map(|l| {
                [
                    weight(
                        format!("{}.weight", l.name),
                        &[l.outputs, l.inputs],
                        l.inputs,
                    ),
                    zeros(format!("{}.bias", l.name), &[l.outputs]),
                ]
            })
            .collect();
    }
    let (n, t, c, k, o) = (
        config.nodes,
        config.window,
        config.channels,
        config.kernel,
        config.outputs,
    );
    let mut out = Vec::new();
    for l in 0..config.blocks {
        let ci = config.block_input(l);
        let p = |s: &str| format!("blocks.{l}.{s}");
        if config.variant.attention() {
            out.push(weight(p("tat.U1"), &[n], n));
            out.push(weight(p("tat.U2"), &[ci, n], ci));
            out.push(weight(p("tat.U3"), &[ci], ci));
            out.push(zeros(p("tat.be"), &[t, t]));
            out.push(weight(p("tat.Ve"), &[t, t], t));
            out.push(weight(p("sat.W1"), &[t], t));
            out.push(weight(p("sat.W2"), &[ci, t], ci));
            out.push(weight(p("sat.W3"), &[ci], ci));
            out.push(zeros(p("sat.bs"), &[n, n]));
            out.push(weight(p("sat.Vs"), &[n, n], n));
        }
        if config.variant.graph_attention() {
            // Per head of C/heads channels, its attention vectors' share.
            let width = c / config.heads;
            out.push(weight(p("gat.W"), &[ci, c], ci));
            out.push(weight(p("gat.a_src"), &[c], width));
            out.push(weight(p("gat.a_dst"), &[c], width));
        } else {
            out.push(spec(
                p("gwc.theta"),
                &[config.graph_terms()],
                Init::Ones,
                false,
            ));
            out.push(weight(p("gwc.W"), &[ci, c], ci));
        }
        out.push(weight(p("tcn.filter.weight"), &[c, c, k], c * k));
        out.push(zeros(p("tcn.filter.bias"), &[c]));
        if config.variant.gated() {
            out.push(weight(p("tcn.gate.weight"), &[c, c, k], c * k));
            out.push(zeros(p("tcn.gate.bias"), &[c]));
        }
        out.push(weight(p("res.weight"), &[c, ci], ci));
        out.push(zeros(p("res.bias"), &[c]));
        out.push(spec(p("ln.gamma"), &[c], Init::Ones, false));
        out.push(zeros(p("ln.beta"), &[c]));
    }
    out.push(weight("head.weight".into(), &[o, n * c], n * c));
    out.push(zeros("head.bias".into(), &[o]));
    out
}

/// Host copy of all parameters (f32, docs/model.md layouts), in [`param_specs`] order.
#[derive(Clone, Debug, PartialEq)]
pub struct Parameters {
    /// Name, shape and initialisation of each tensor.
    pub specs: Vec<ParamSpec>,
    /// Each tensor's values, row-major, same order.
    pub values: Vec<Vec<f32>>,
}

impl Parameters {
    /// Fresh parameters drawn from `seed` (reproducible: one ChaCha8 stream, table order).
    ///
    /// ```
    /// use iastgcn::model::{ModelConfig, Parameters, Variant};
    ///
    /// // The paper shape (T 100, C 64, L 5) of docs/model.md "Parameter names".
    /// let params = Parameters::init(&ModelConfig::default(), 1);
    /// assert_eq!((params.count(), params.specs.len()), (295_658, 102));
    /// assert_eq!(params.get("head.bias"), &[0.0; 6]);
    ///
    /// // ST-GAT at the same shape: iastgcn-a's blocks with a graph attention as step 3.
    /// let st_gat = ModelConfig {
    ///     variant: Variant::StGat,
    ///     ..ModelConfig::default()
    /// };
    /// let params = Parameters::init(&st_gat, 1);
    /// assert_eq!((params.count(), params.specs.len()), (163_654, 57));
    /// ```
    pub fn init(config: &ModelConfig, seed: u64) -> Parameters {
        let specs = param_specs(config);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let values = specs
            .iter()
            .map(|s| match s.init {
                Init::Zeros => vec![0.0; s.numel()],
                Init::Ones => vec![1.0; s.numel()],
                Init::HeUniform { fan_in } => {
                    let a = (6.0 / fan_in as f64).sqrt();
                    (0..s.numel())
                        .map(|_| rng.random_range(-a..a) as f32)
                        .collect()
                }
            })
            .collect();
        Parameters { specs, values }
    }

    /// Position of parameter `name` in the table; `None` for an unknown name.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.specs.iter().position(|s| s.name == name)
    }

    /// The values of parameter `name` (panics on an unknown name: names come from the table).
    pub fn get(&self, name: &str) -> &[f32] {
        // invariant: callers ask for names of param_specs(config); a checkpoint's tensors
        // are checked against those specs when it is loaded.
        let i = self
            .index(name)
            .unwrap_or_else(|| panic!("no parameter named {name}"));
        &self.values[i]
    }

    /// The values of parameter `name`, to change (panics on an unknown name).
    pub fn get_mut(&mut self, name: &str) -> &mut Vec<f32> {
        // invariant: as for `get`.
        let i = self
            .index(name)
            .unwrap_or_else(|| panic!("no parameter named {name}"));
        &mut self.values[i]
    }

    /// Total number of scalars.
    pub fn count(&self) -> usize {
        self.specs.iter().map(ParamSpec::numel).sum()
    }
}

/// The fixed matrices that θ combines into Ψ = Σ_k θ_k · basis_k, as `[terms, N, N]`
/// row-major f64. For the wavelet variants basis_k = ψ_s[:, k] ψ_s⁻¹[k, :] (so that
/// Σ_k θ_k basis_k = ψ_s diag(θ) ψ_s⁻¹, docs/model.md step 3); for `iastgcn-s` basis_k = T_k(L̃);
/// for `st-gat` one matrix, its graph attention's neighbour mask (1 on the edges and the
/// diagonal, 0 elsewhere); empty for the dense and recurrent baselines.
pub fn graph_basis(graph: &Graph, config: &ModelConfig) -> Vec<f64> {
    let n = graph.len();
    if config.graph_terms() == 0 {
        return Vec::new();
    }
    if config.variant.graph_attention() {
        let a = graph.adjacency();
        return (0..n * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                if i == j || a[(i, j)] != 0.0 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
    }
    let spectral = graph.spectral();
    let mut out = Vec::with_capacity(config.graph_terms() * n * n);
    match config.variant {
        Variant::Chebyshev => {
            for t in spectral.chebyshev(config.chebyshev_order) {
                for i in 0..n {
                    for j in 0..n {
                        out.push(t[(i, j)]);
                    }
                }
            }
        }
        _ => {
            let psi = spectral.wavelet(config.scale);
            let inv = spectral.wavelet_inverse(config.scale);
            for k in 0..n {
                for i in 0..n {
                    for j in 0..n {
                        out.push(psi[(i, k)] * inv[(k, j)]);
                    }
                }
            }
        }
    }
    out
}

/// How much each block's graph convolution mixes nodes: ‖Ψ − diag Ψ‖_F / ‖diag Ψ‖_F with
/// Ψ = Σ_k θ_k · basis_k ([`graph_basis`], docs/model.md step 3). 0 for the wavelet
/// convolution with every θ equal (it is then a multiple of the identity), about 0.95 for
/// the Chebyshev one at θ = 1 on the embedded graph. One value per block, in order;
/// empty for a variant without `blocks.{l}.gwc.theta` (the baselines).
pub fn graph_mixing(config: &ModelConfig, graph: &Graph, params: &Parameters) -> Vec<f64> {
    let (n, terms) = (graph.len(), config.graph_terms());
    let theta = |l: usize| {
        params
            .index(&format!("blocks.{l}.gwc.theta"))
            .map(|i| &params.values[i])
            .filter(|t| t.len() == terms && terms > 0)
    };
    if theta(0).is_none() {
        return Vec::new();
    }
    let basis = graph_basis(graph, config);
    (0..config.blocks)
        .map_while(theta)
        .map(|theta| {
            let mut psi = vec![0f64; n * n];
            for (&t, b) in theta.iter().zip(basis.chunks(n * n)) {
                for (p, b) in psi.iter_mut().zip(b) {
                    *p += t as f64 * b;
                }
            }
            let (mut off, mut diag) = (0.0, 0.0);
            for (k, p) in psi.iter().enumerate() {
                if k / n == k % n {
                    diag += p * p;
                } else {
                    off += p * p;
                }
            }
            (off / diag.max(f64::MIN_POSITIVE)).sqrt()
        })
        .collect()
}
