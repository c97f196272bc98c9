//! The native CPU forward (`model::NativeForward`) against the WGSL inference forward and
//! the f64 reference: every IASTGCN variant and ST-GAT at a small shape, IASTGCN and ST-GAT
//! at the demo's shape, IASTGCN at the paper's, the dense and recurrent baselines and
//! ConvLSTM; bad inputs are refused.

mod common;

use common::parameters;
use iastgcn::graph::Graph;
use iastgcn::model::reference;
use iastgcn::model::{graph_basis, ModelConfig, NativeForward, Network, Variant};
use iastgcn::testing::{compare, gpu, rng, to_f32, uniform, Tolerance};

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// `windows` random windows through the native path, one at a time.
fn native(config: &ModelConfig, p: &iastgcn::model::Parameters, x: &[f32]) -> Vec<f64> {
    let mut net = NativeForward::new(config, &Graph::default_asset(), p).unwrap();
    let len = config.nodes * config.features * config.window;
    let mut y = vec![0f32; config.outputs];
    let mut out = Vec::new();
    for w in x.chunks(len) {
        net.forward(w, &mut y).unwrap();
        out.extend(f64s(&y));
    }
    out
}

/// Tolerance `rel` of the largest output (f32 sums lose absolute precision).
fn scaled(expected: &[f64], rel: f64) -> Tolerance {
    let scale = expected.iter().fold(0f64, |m, v| m.max(v.abs()));
    Tolerance::new(rel * scale.max(1e-30), rel)
}

/// Native against the GPU and the reference at `config`, `windows` windows.
fn check(config: &ModelConfig, seed: u64, windows: usize, rel: f64) {
    let g = gpu();
    let graph = Graph::default_asset();
    let p = parameters(config, seed);
    let len = config.nodes * config.features * config.window;
    let x = to_f32(&uniform(&mut rng(seed + 50), windows * len, -1.0, 1.0));
    let ours = native(config, &p, &x);
    let net = Network::for_inference(&g, config, &graph, windows).unwrap();
    net.load_parameters(&g, &p).unwrap();
    let device = f64s(&net.predict(&g, &x).unwrap());
    let name = format!(
        "{} C{} T{} L{}",
        config.variant, config.channels, config.window, config.blocks
    );
    compare(
        &format!("{name}: native vs WGSL"),
        &ours,
        &device,
        scaled(&device, rel),
    )
    .unwrap();
    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let basis = graph_basis(&graph, config);
    let tape = reference::forward(config, &basis, &p.specs, &params, &f64s(&x), windows, None);
    compare(
        &format!("{name}: native vs f64 reference"),
        &ours,
        &tape.output,
        scaled(&tape.output, rel),
    )
    .unwrap();
}

#[test]
fn every_variant_matches_the_wgsl_forward_and_the_reference() {
    let st_blocks = Variant::IASTGCN.into_iter().chain([Variant::StGat]);
    for (i, variant) in st_blocks.enumerate() {
        check(
            &ModelConfig::gradient_check(variant),
            30 + i as u64,
            3,
            1e-5,
        );
    }
}

/// Dilations whose reach d·(K−1) exceeds the window (16·2 = 32 > 12 in the last block):
/// those taps read only the zeros before the window.
#[test]
fn dilation_beyond_the_window_matches() {
    let config = ModelConfig {
        window: 12,
        blocks: 5,
        ..ModelConfig::gradient_check(Variant::Iastgcn)
    };
    check(&config, 35, 2, 1e-5);
}

#[test]
fn demo_shape_matches() {
    let config = ModelConfig {
        window: 48,
        channels: 16,
        blocks: 3,
        ..ModelConfig::default()
    };
    check(&config, 40, 2, 1e-5);
}

/// ST-GAT at the demo's shape: 4 heads of 4 channels on the 14-node graph.
#[test]
fn st_gat_demo_shape_matches() {
    let config = ModelConfig {
        variant: Variant::StGat,
        window: 48,
        channels: 16,
        blocks: 2,
        ..ModelConfig::default()
    };
    check(&config, 42, 2, 1e-5);
}

#[test]
fn paper_shape_matches() {
    check(&ModelConfig::default(), 41, 1, 1e-5);
}

/// One window split over threads (`NativeForward::set_threads`) gives the outputs of one
/// thread bit for bit, in every variant, at a size large enough that the convolution,
/// X·E' and the per-node loops are split (C 64, T 64: 410k multiply-adds per node); the
/// demo's size stays on one thread and agrees too.
#[test]
fn threads_do_not_change_the_outputs() {
    let graph = Graph::default_asset();
    let large = |variant| ModelConfig {
        variant,
        window: 64,
        blocks: 2,
        ..ModelConfig::default()
    };
    let demo = ModelConfig {
        window: 48,
        channels: 16,
        blocks: 2,
        ..ModelConfig::default()
    };
    let configs = Variant::IASTGCN.into_iter().map(large).chain([demo]);
    for (i, config) in configs.enumerate() {
        let p = parameters(&config, 60 + i as u64);
        let len = config.nodes * config.features * config.window;
        let x = to_f32(&uniform(&mut rng(70 + i as u64), 2 * len, -1.0, 1.0));
        let mut one = NativeForward::new(&config, &graph, &p).unwrap();
        let mut three = NativeForward::new(&config, &graph, &p).unwrap();
        three.set_threads(3);
        assert_eq!((one.threads(), three.threads()), (1, 3));
        let (mut y1, mut y3) = (vec![0f32; 6], vec![0f32; 6]);
        for w in x.chunks(len) {
            one.forward(w, &mut y1).unwrap();
            three.forward(w, &mut y3).unwrap();
            assert!(y1.iter().all(|v| v.is_finite()));
            let bits = |y: &[f32]| y.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&y1),
                bits(&y3),
                "{} C{}",
                config.variant,
                config.channels
            );
        }
    }
}

/// New weights through `set_parameters` give what a forward built with them gives, bit for
/// bit (the working memory left by the old weights is not read), for a block variant and
/// a dense baseline; parameters of another shape are refused and leave the old ones.
#[test]
fn set_parameters_equals_a_new_forward() {
    let graph = Graph::default_asset();
    let configs = [
        ModelConfig {
            window: 24,
            channels: 8,
            blocks: 2,
            ..ModelConfig::default()
        },
        ModelConfig {
            variant: Variant::Mlp,
            window: 5,
            hidden: 6,
            ..ModelConfig::default()
        },
    ];
    for (i, config) in configs.iter().enumerate() {
        let (old, new) = (
            parameters(config, 80 + i as u64),
            parameters(config, 90 + i as u64),
        );
        let len = config.nodes * config.features * config.window;
        let x = to_f32(&uniform(&mut rng(95 + i as u64), len, -1.0, 1.0));
        let mut reused = NativeForward::new(config, &graph, &old).unwrap();
        let mut fresh = NativeForward::new(config, &graph, &new).unwrap();
        let (mut y_old, mut y_reused, mut y_fresh) = (vec![0f32; 6], vec![0f32; 6], vec![0f32; 6]);
        reused.forward(&x, &mut y_old).unwrap();
        reused.set_parameters(&new).unwrap();
        reused.forward(&x, &mut y_reused).unwrap();
        fresh.forward(&x, &mut y_fresh).unwrap();
        assert_ne!(
            y_old, y_fresh,
            "{}: the two weight sets differ",
            config.variant
        );
        assert_eq!(y_reused, y_fresh, "{}", config.variant);
        let other = ModelConfig {
            channels: config.channels + 1,
            hidden: config.hidden + 1,
            ..config.clone()
        };
        let err = reused.set_parameters(&parameters(&other, 1));
        assert!(err.is_err(), "{}: another shape was taken", config.variant);
        reused.forward(&x, &mut y_reused).unwrap();
        assert_eq!(
            y_reused, y_fresh,
            "{}: a refused set changed the weights",
            config.variant
        );
    }
}

/// A baseline's native outputs on 3 random windows (seed `seed`) against the WGSL
/// forward and against `reference` (the f64 reference's outputs for the parameters and
/// windows in f64), each within 1e-5 of the output scale.
fn check_baseline(
    name: &str,
    config: &ModelConfig,
    seed: u64,
    reference: impl Fn(&iastgcn::model::Parameters, &[Vec<f64>], &[f64], usize) -> Vec<f64>,
) {
    let g = gpu();
    let windows = 3;
    let p = parameters(config, seed);
    let len = config.nodes * config.features * config.window;
    let x = to_f32(&uniform(&mut rng(seed + 10), windows * len, -1.5, 1.5));
    let ours = native(config, &p, &x);
    let net = Network::for_inference(&g, config, &Graph::default_asset(), windows).unwrap();
    net.load_parameters(&g, &p).unwrap();
    let device = f64s(&net.predict(&g, &x).unwrap());
    let scale = scaled(&device, 1e-5);
    compare(&format!("{name}: native vs WGSL"), &ours, &device, scale).unwrap();
    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let expected = reference(&p, &params, &f64s(&x), windows);
    let scale = scaled(&expected, 1e-5);
    compare(
        &format!("{name}: native vs f64 reference"),
        &ours,
        &expected,
        scale,
    )
    .unwrap();
}

/// The dense baselines (14-node graph, F = 3, T = 5, H = 6): native against the WGSL
/// forward and the f64 reference of `model::dense::reference`.
#[test]
fn dense_baselines_match_the_wgsl_forward_and_the_reference() {
    use iastgcn::model::dense::Architecture;
    let graph = Graph::default_asset();
    for (i, variant) in Variant::DENSE.into_iter().enumerate() {
        let config = ModelConfig {
            variant,
            window: 5,
            hidden: 6,
            ..ModelConfig::default()
        };
        let inputs = Architecture::of(&config)
            .unwrap()
            .input_indices(&graph, config.features)
            .unwrap();
        check_baseline(variant.name(), &config, 60 + i as u64, |p, params, x, b| {
            iastgcn::model::dense::reference::forward(&config, &inputs, &p.specs, params, x, b)
                .output
        });
    }
}

/// The recurrent baselines (14-node graph, F = 3, T = 5, H = 6; EAT-GCN with its
/// Chebyshev supports, T_0 = I among them): native against the WGSL forward and the f64
/// reference of `model::recurrent::reference`.
#[test]
fn recurrent_baselines_match_the_wgsl_forward_and_the_reference() {
    use iastgcn::model::recurrent::supports;
    let graph = Graph::default_asset();
    for (i, variant) in Variant::RECURRENT.into_iter().enumerate() {
        let config = ModelConfig {
            variant,
            window: 5,
            hidden: 6,
            ..ModelConfig::default()
        };
        let s = supports(&graph, &config);
        check_baseline(variant.name(), &config, 80 + i as u64, |p, params, x, b| {
            iastgcn::model::recurrent::reference::forward(&config, &s, &p.specs, params, x, b)
                .output
        });
    }
}

/// ConvLSTM (the 14 × 3 grid, T = 5, C = 3 state channels, 3×3 and 5×5 kernels): native
/// against the WGSL forward and the f64 reference of `model::conv_lstm::reference`.
#[test]
fn conv_lstm_matches_the_wgsl_forward_and_the_reference() {
    for (i, kernel) in [3, 5].into_iter().enumerate() {
        let config = ModelConfig {
            variant: Variant::ConvLstm,
            window: 5,
            channels: 3,
            kernel,
            ..ModelConfig::default()
        };
        let name = format!("convlstm k = {kernel}");
        check_baseline(&name, &config, 85 + i as u64, |p, params, x, b| {
            iastgcn::model::conv_lstm::reference::forward(&config, &p.specs, params, x, b).output
        });
    }
}

#[test]
fn refuses_bad_inputs() {
    let graph = Graph::default_asset();
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let mut net = NativeForward::new(&config, &graph, &parameters(&config, 1)).unwrap();
    let mut y = [0f32; 6];
    let e = net.forward(&[0.0; 5], &mut y).unwrap_err().to_string();
    assert!(e.contains("N·F·T"), "{e}");
    // Parameters of another shape name the tensor.
    let other = ModelConfig {
        channels: config.channels + 2,
        ..config.clone()
    };
    let e = NativeForward::new(&config, &graph, &parameters(&other, 1))
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("blocks.0."), "{e}");
}
