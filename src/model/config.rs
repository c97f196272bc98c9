//! The network's configuration (docs/model.md "Notation") and its variants.

use serde::{Deserialize, Serialize};

/// Which network the engine runs (docs/model.md "Variants"); stored in checkpoint metadata.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Variant {
    /// The full model.
    #[serde(rename = "iastgcn")]
    Iastgcn,
    /// No attention: steps 1–2 skipped (X_s = X).
    #[serde(rename = "iastgcn-a")]
    NoAttention,
    /// Step 4 is one plain causal convolution (ungated, undilated) with ReLU.
    #[serde(rename = "iastgcn-t")]
    PlainTemporal,
    /// Step 3 uses a Chebyshev graph convolution on the scaled Laplacian.
    #[serde(rename = "iastgcn-s")]
    Chebyshev,
    /// Instantaneous baseline: a ReLU MLP on every node's features at the window's last
    /// step only (no history, no graph).
    #[serde(rename = "mlp")]
    Mlp,
    /// Offline pose→error baseline of Table V [15]: a tanh feed-forward ANN on the joint
    /// inputs (`ModelConfig::joint_inputs`, Q1–Q5 on the hybrid) at the last step.
    #[serde(rename = "bkls-ann")]
    BklsAnn,
    /// Offline pose→error baseline of Table V [17]: a one-hidden-layer tanh ANN on the
    /// joint inputs whose starting weights a seeded flower-pollination search picks.
    #[serde(rename = "ann-bfpa")]
    AnnBfpa,
    /// Offline pose→error baseline of Table V [19]: a residual network on the joint inputs.
    #[serde(rename = "erc")]
    Erc,
    /// Spatio-temporal baseline of Table III [23]: a graph convolution inside a GRU,
    /// run over the window's steps.
    #[serde(rename = "tgcn")]
    Tgcn,
    /// Spatio-temporal baseline of Table III [26]: a GRU whose gates are Chebyshev graph
    /// convolutions, with an attention over the window's steps that weighs every step's
    /// state into the head's input.
    #[serde(rename = "eat-gcn")]
    EatGcn,
    /// Spatio-temporal baseline of Table III [27]: ST blocks whose spatial layer is a
    /// multi-head graph attention (GAT) over each step, then the gated dilated
    /// convolution; no temporal or spatial attention of IASTGCN's kind.
    #[serde(rename = "st-gat")]
    StGat,
    /// Spatio-temporal baseline of Table III [25]: a convolutional LSTM over the node ×
    /// feature grid of every step (a 2-D Euclidean convolution, no graph).
    #[serde(rename = "convlstm")]
    ConvLstm,
}

/// What a variant's network is built from (docs/model.md "Variants" and "Baselines").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Stacked ST blocks and the head (IASTGCN and its ablations).
    StBlocks,
    /// Dense layers on the last step of the window ([`crate::model::dense`]).
    Dense,
    /// A recurrent cell over the window's steps ([`crate::model::recurrent`]).
    Recurrent,
    /// A convolutional LSTM over the window's steps ([`crate::model::conv_lstm`]).
    ConvRecurrent,
}

impl Variant {
    /// Every variant: IASTGCN, its ablations, then the baselines.
    pub const ALL: [Variant; 12] = [
        Variant::Iastgcn,
        Variant::NoAttention,
        Variant::PlainTemporal,
        Variant::Chebyshev,
        Variant::Mlp,
        Variant::BklsAnn,
        Variant::AnnBfpa,
        Variant::Erc,
        Variant::Tgcn,
        Variant::EatGcn,
        Variant::StGat,
        Variant::ConvLstm,
    ];

    /// IASTGCN and its three ablations: the variants built from ST blocks.
    pub const IASTGCN: [Variant; 4] = [
        Variant::Iastgcn,
        Variant::NoAttention,
        Variant::PlainTemporal,
        Variant::Chebyshev,
    ];

    /// The dense baselines: the instantaneous MLP and the three offline pose→error models.
    pub const DENSE: [Variant; 4] = [
        Variant::Mlp,
        Variant::BklsAnn,
        Variant::AnnBfpa,
        Variant::Erc,
    ];

    /// The spatio-temporal baselines of Table III built so far.
    pub const SPATIO_TEMPORAL: [Variant; 4] = [
        Variant::ConvLstm,
        Variant::Tgcn,
        Variant::EatGcn,
        Variant::StGat,
    ];

    /// The recurrent baselines: a GRU over the window's steps ([`crate::model::recurrent`]).
    pub const RECURRENT: [Variant; 2] = [Variant::Tgcn, Variant::EatGcn];

    /// What the network is built from.
    pub fn family(self) -> Family {
        if Variant::DENSE.contains(&self) {
            Family::Dense
        } else if Variant::RECURRENT.contains(&self) {
            Family::Recurrent
        } else if self == Variant::ConvLstm {
            Family::ConvRecurrent
        } else {
            Family::StBlocks
        }
    }

    /// Every name, comma-separated, for help texts and error messages.
    pub fn names() -> String {
        Variant::ALL.map(Variant::name).join(", ")
    }

    /// The name in configs, checkpoint metadata and reports.
    ///
    /// ```
    /// use iastgcn::model::Variant;
    ///
    /// assert_eq!(Variant::NoAttention.name(), "iastgcn-a");
    /// assert_eq!(Variant::parse("iastgcn-s"), Some(Variant::Chebyshev));
    /// assert_eq!(Variant::parse("erc"), Some(Variant::Erc));
    /// assert_eq!(Variant::parse("convlstm"), Some(Variant::ConvLstm));
    /// assert_eq!(Variant::parse("lstm"), None);
    /// ```
    pub fn name(self) -> &'static str {
        match self {
            Variant::Iastgcn => "iastgcn",
            Variant::NoAttention => "iastgcn-a",
            Variant::PlainTemporal => "iastgcn-t",
            Variant::Chebyshev => "iastgcn-s",
            Variant::Mlp => "mlp",
            Variant::BklsAnn => "bkls-ann",
            Variant::AnnBfpa => "ann-bfpa",
            Variant::Erc => "erc",
            Variant::Tgcn => "tgcn",
            Variant::EatGcn => "eat-gcn",
            Variant::StGat => "st-gat",
            Variant::ConvLstm => "convlstm",
        }
    }

    /// The variant of that name; `None` for any other.
    pub fn parse(name: &str) -> Option<Variant> {
        Variant::ALL.into_iter().find(|v| v.name() == name)
    }

    /// True when the blocks run the temporal and spatial attention (steps 1–2).
    pub fn attention(self) -> bool {
        matches!(
            self,
            Variant::Iastgcn | Variant::PlainTemporal | Variant::Chebyshev
        )
    }

    /// True when step 4 is the gated dilated convolution (not the plain one).
    pub fn gated(self) -> bool {
        matches!(
            self,
            Variant::Iastgcn | Variant::NoAttention | Variant::Chebyshev | Variant::StGat
        )
    }

    /// True when step 3 is a multi-head graph attention (ST-GAT) instead of a graph
    /// convolution.
    pub fn graph_attention(self) -> bool {
        self == Variant::StGat
    }
}

impl std::fmt::Display for Variant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The largest value of any size field (nodes, window, channels, …) a config may have.
pub const MAX_SIZE: usize = 1 << 20;
/// Shapes and hyper-parameters of one network. Defaults are docs/model.md's paper shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Which network.
    pub variant: Variant,
    /// N: graph nodes.
    pub nodes: usize,
    /// F: input features per node and step.
    pub features: usize,
    /// T: window length.
    pub window: usize,
    /// C: hidden channels (also ConvLSTM's state channels).
    pub channels: usize,
    /// L: stacked ST blocks.
    pub blocks: usize,
    /// K: temporal kernel size (ConvLSTM: the side of its k×k convolution, odd).
    pub kernel: usize,
    /// s: wavelet scale.
    pub scale: f64,
    /// Order of the Chebyshev graph convolutions of `iastgcn-s` and `eat-gcn`
    /// (T_0..T_{order−1}).
    pub chebyshev_order: usize,
    /// O: outputs.
    pub outputs: usize,
    /// H: width of the baselines' hidden layers and recurrent state (unused by the
    /// ST-block variants).
    pub hidden: usize,
    /// Attention heads of `st-gat`'s graph attention (a divisor of `channels`).
    pub heads: usize,
    /// Inverted dropout probability on each block's output (training only).
    pub dropout: f64,
    /// LayerNorm ε.
    pub eps: f64,
    /// The graph nodes the offline pose→error baselines (`bkls-ann`, `ann-bfpa`, `erc`)
    /// read: the robot's joint inputs, Q1–Q5 on the hybrid machine, the joints' names on a
    /// serial arm. Unused by the other variants.
    pub joint_inputs: Vec<String>,
    /// Ticks after the window's last tick whose residual the network predicts (0: the
    /// last tick's own; 1: the next tick's, the one a correction computed now acts on,
    /// docs/model.md "Look-ahead"). With 1 or more the default graph adds the planned
    /// motion as nodes (`assets/graph-look-ahead.toml`).
    pub look_ahead: usize,
}

/// The most ticks ahead a model may predict.
pub const MAX_LOOK_AHEAD: usize = 50;

impl Default for ModelConfig {
    fn default() -> ModelConfig {
        ModelConfig {
            variant: Variant::Iastgcn,
            nodes: 14,
            features: 3,
            window: 100,
            channels: 64,
            blocks: 5,
            kernel: 3,
            scale: 1.0,
            chebyshev_order: 3,
            outputs: 6,
            hidden: 64,
            heads: 4,
            dropout: 0.2,
            eps: 1e-5,
            joint_inputs: crate::graph::HYBRID_JOINT_INPUTS.map(String::from).to_vec(),
            look_ahead: 0,
        }
    }
}

impl ModelConfig {
    /// The small shape of the whole-model gradient checks (docs/model.md defaults otherwise):
    /// F = 3, T = 16, C = 4, L = 2, K = 3 on the 14-node graph, dropout 0.2; 2 heads.
    pub fn gradient_check(variant: Variant) -> ModelConfig {
        ModelConfig {
            variant,
            window: 16,
            channels: 4,
            blocks: 2,
            heads: 2,
            ..ModelConfig::default()
        }
    }

    /// The look-ahead in a report's words: "no look-ahead" or "look-ahead 1 tick".
    pub fn look_ahead_words(&self) -> String {
        match self.look_ahead {
            0 => "no look-ahead".into(),
            1 => "look-ahead 1 tick".into(),
            n => format!("look-ahead {n} ticks"),
        }
    }

    /// C_in of block `l` (0-based): F for the first block, C afterwards.
    pub fn block_input(&self, l: usize) -> usize {
        if l == 0 {
            self.features
        } else {
            self.channels
        }
    }

    /// Dilation of block `l` (0-based): 2^l, or 1 for the plain temporal convolution.
    pub fn dilation(&self, l: usize) -> usize {
        if self.variant.gated() {
            1 << l
        } else {
            1
        }
    }

    /// Number of graph basis matrices Ψ is a θ-combination of: N wavelets or the
    /// Chebyshev order; 1 for `st-gat` (its neighbour mask); 0 for the dense and recurrent
    /// baselines, which take no basis.
    pub fn graph_terms(&self) -> usize {
        match (self.variant, self.variant.family()) {
            (_, Family::Dense | Family::Recurrent | Family::ConvRecurrent) => 0,
            (Variant::Chebyshev, _) => self.chebyshev_order,
            (Variant::StGat, _) => 1,
            _ => self.nodes,
        }
    }

    /// Checks that the shapes make sense; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("nodes", self.nodes),
            ("features", self.features),
            ("window", self.window),
            ("channels", self.channels),
            ("blocks", self.blocks),
            ("kernel", self.kernel),
            ("chebyshev_order", self.chebyshev_order),
            ("outputs", self.outputs),
            ("hidden", self.hidden),
            ("heads", self.heads),
        ];
        if let Some((name, _)) = positive.iter().find(|(_, v)| *v == 0) {
            return Err(format!("model config: {name} must be positive"));
        }
        if let Some((name, v)) = positive.iter().find(|(_, v)| *v > MAX_SIZE) {
            return Err(format!(
                "model config: {name} = {v} is beyond the largest size this engine takes ({MAX_SIZE})"
            ));
        }
        if self.look_ahead > MAX_LOOK_AHEAD {
            return Err(format!(
                "model config: look_ahead = {} ticks is beyond {MAX_LOOK_AHEAD}",
                self.look_ahead
            ));
        }
        if self.blocks > 16 {
            return Err(format!(
                "model config: blocks = {} (dilation 2^l overflows beyond 16)",
                self.blocks
            ));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(format!(
                "model config: dropout = {} must be in [0, 1)",
                self.dropout
            ));
        }
        if self.variant == Variant::ConvLstm && self.kernel.is_multiple_of(2) {
            return Err(format!(
                "model config: kernel = {} must be odd for convlstm (a centred k×k convolution)",
                self.kernel
            ));
        }
        if self.variant.graph_attention() && !self.channels.is_multiple_of(self.heads) {
            return Err(format!(
                "model config: heads = {} must divide channels = {} (each head attends over C/heads channels)",
                self.heads, self.channels
            ));
        }
        if matches!(
            self.variant,
            Variant::BklsAnn | Variant::AnnBfpa | Variant::Erc
        ) {
            if self.joint_inputs.is_empty() {
                return Err(format!(
                    "model config: joint_inputs is empty: {} reads the joint-input nodes it names",
                    self.variant
                ));
            }
            for (i, name) in self.joint_inputs.iter().enumerate() {
                if let Some(first) = self.joint_inputs[..i].iter().position(|n| n == name) {
                    return Err(format!(
                        "model config: joint_inputs names {name:?} twice (entries {} and {})",
                        first + 1,
                        i + 1
                    ));
                }
            }
        }
        if !(self.eps.is_finite() && self.eps > 0.0) {
            return Err(format!(
                "model config: eps = {} must be a finite positive number",
                self.eps
            ));
        }
        if !self.scale.is_finite() {
            return Err(format!(
                "model config: scale = {} must be finite",
                self.scale
            ));
        }
        Ok(())
    }
}
