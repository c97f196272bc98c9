//! Checkpoints: save → load gives identical parameters and identical GPU outputs; bad
//! files are rejected with a message naming the file and what is wrong. The predictor
//! (window, batch, ring buffer) against the network, the `init` / `forward` library calls
//! (interop) and their CLI.

use std::sync::Arc;

use iastgcn::error::Error;
use iastgcn::gpu::GpuError;
use iastgcn::graph::Graph;
use iastgcn::interop;
use iastgcn::model::{
    Backend, Checkpoint, ModelConfig, ModelError, Network, Normalization, Parameters, Predictor,
    Variant,
};
use iastgcn::testing::{gpu, rng, to_f32, uniform};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};

fn small(variant: Variant) -> ModelConfig {
    ModelConfig {
        variant,
        window: 16,
        channels: 8,
        blocks: 2,
        ..ModelConfig::default()
    }
}

fn checkpoint(variant: Variant, seed: u64) -> Checkpoint {
    let config = small(variant);
    let mut r = rng(seed);
    let mut normalization = Normalization::identity(&config);
    for row in normalization.feature_mean.iter_mut() {
        *row = uniform(&mut r, 3, -1.0, 1.0);
    }
    for row in normalization.feature_std.iter_mut() {
        *row = uniform(&mut r, 3, 0.5, 2.0);
    }
    normalization.label_mean = uniform(&mut r, 6, -50.0, 50.0);
    normalization.label_std = uniform(&mut r, 6, 10.0, 100.0);
    Checkpoint {
        parameters: Parameters::init(&config, seed),
        config,
        graph: Graph::default_asset(),
        normalization,
    }
}

fn temp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("iastgcn-ckpt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn save_load_round_trip_gives_identical_outputs() {
    let g = gpu();
    for (i, variant) in Variant::ALL.into_iter().enumerate() {
        let ck = checkpoint(variant, 40 + i as u64);
        let path = temp(&format!("{variant}.safetensors"));
        ck.save(&path).unwrap();
        let back = Checkpoint::load(&path).unwrap();
        assert_eq!(
            back.config, ck.config,
            "{variant}: config changed through the file"
        );
        assert_eq!(
            back.graph, ck.graph,
            "{variant}: graph changed through the file"
        );
        assert!(
            back.parameters == ck.parameters,
            "{variant}: parameters changed through the file"
        );
        assert_eq!(
            back.normalization, ck.normalization,
            "{variant}: statistics changed"
        );
        let x = to_f32(&uniform(&mut rng(5), 2 * 14 * 3 * 16, -1.0, 1.0));
        let run = |c: &Checkpoint| {
            let net = Network::for_inference(&g, &c.config, &c.graph, 2).unwrap();
            net.load_parameters(&g, &c.parameters).unwrap();
            assert!(
                net.set_attitude_penalty(&g, 2.0).is_err(),
                "inference has no loss"
            );
            net.predict(&g, &x).unwrap()
        };
        let (a, b) = (run(&ck), run(&back));
        assert!(a.iter().all(|v| v.is_finite()));
        assert_eq!(a, b, "{variant}: outputs differ after save → load");
    }
}

/// The same checkpoint gives the same bytes every time (the header's keys sorted,
/// whatever order the metadata map iterates in), and they still load.
#[test]
fn saved_bytes_are_the_same_every_time() {
    let ck = checkpoint(Variant::Iastgcn, 3);
    let first = ck.to_bytes().unwrap();
    for _ in 0..8 {
        assert_eq!(ck.to_bytes().unwrap(), first);
    }
    let n = u64::from_le_bytes(first[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&first[8..8 + n]).unwrap();
    let at = |key: &str| header.find(&format!("\"{key}\"")).unwrap();
    assert!(at("__metadata__") < at("config"));
    assert!(at("config") < at("format"));
    assert!(at("format") < at("graph"));
    assert!(at("graph") < at("normalization"));
    assert!(at("normalization") < at("variant"));
    let back = Checkpoint::from_bytes(&first, "sorted").unwrap();
    assert_eq!(back.parameters.values, ck.parameters.values);
}

/// Rewrites a checkpoint's tensors and metadata through `edit`, returning the bytes.
fn edited(
    ck: &Checkpoint,
    edit: impl Fn(
        &mut Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
        &mut std::collections::HashMap<String, String>,
    ),
) -> Vec<u8> {
    let bytes = ck.to_bytes().unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    let mut tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)> = st
        .tensors()
        .into_iter()
        .map(|(n, t)| (n, t.dtype(), t.shape().to_vec(), t.data().to_vec()))
        .collect();
    edit(&mut tensors, &mut meta);
    let views: Vec<(String, TensorView)> = tensors
        .iter()
        .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap()))
        .collect();
    safetensors::serialize(views, Some(meta)).unwrap()
}

fn error_of(bytes: &[u8]) -> String {
    match Checkpoint::from_bytes(bytes, "bad.safetensors") {
        Ok(_) => panic!("a bad checkpoint was accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_checkpoints_are_rejected_with_a_clear_message() {
    let ck = checkpoint(Variant::Iastgcn, 1);
    let good = ck.to_bytes().unwrap();
    let expect = |bytes: &[u8], needles: &[&str]| {
        let msg = error_of(bytes);
        assert!(msg.starts_with("bad.safetensors: "), "{msg}");
        for n in needles {
            assert!(msg.contains(n), "message {msg:?} lacks {n:?}");
        }
    };
    expect(&good[..good.len() - 10], &["not a valid safetensors file"]);
    expect(b"garbage", &["not a valid safetensors file"]);
    let name = "blocks.1.tcn.gate.weight";
    expect(
        &edited(&ck, |ts, _| ts.retain(|t| t.0 != name)),
        &[name, "missing"],
    );
    expect(
        &edited(&ck, |ts, _| {
            let t = ts.iter_mut().find(|t| t.0 == name).unwrap();
            t.2 = vec![8, 24];
        }),
        &[name, "[8, 24]", "[8, 8, 3]"],
    );
    expect(
        &edited(&ck, |ts, _| {
            let t = ts.iter_mut().find(|t| t.0 == "head.bias").unwrap();
            t.1 = Dtype::I32;
        }),
        &["head.bias", "I32"],
    );
    expect(
        &edited(&ck, |ts, _| {
            let t = ts.iter_mut().find(|t| t.0 == "head.bias").unwrap();
            t.3[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        }),
        &["head.bias", "element 1", "NaN"],
    );
    expect(
        &edited(&ck, |ts, _| {
            ts.push(("blocks.9.extra".into(), Dtype::F32, vec![1], vec![0; 4]))
        }),
        &["unexpected tensor blocks.9.extra"],
    );
    expect(
        &edited(&ck, |_, m| {
            m.insert("variant".into(), "iastgcn-a".into());
        }),
        &["variant", "iastgcn-a"],
    );
    expect(
        &edited(&ck, |_, m| {
            m.insert("config".into(), r#"{"channels": 8, "colour": 3}"#.into());
        }),
        &["config", "colour"],
    );
    expect(
        &edited(&ck, |_, m| {
            m.remove("normalization");
        }),
        &["normalization"],
    );
    // A checkpoint of another shape does not load into this network.
    let g = gpu();
    let net = Network::for_inference(&g, &ck.config, &ck.graph, 1).unwrap();
    let other = checkpoint(Variant::NoAttention, 2);
    let err = net
        .load_parameters(&g, &other.parameters)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("parameter tensors") || err.contains("expected"),
        "{err}"
    );
}

#[test]
fn predictor_matches_network_in_every_mode() {
    let g = Arc::new(gpu());
    let ck = checkpoint(Variant::Iastgcn, 7);
    let c = &ck.config;
    let (n, f, t) = (c.nodes, c.features, c.window);
    let len = n * f * t;
    let windows = 5;
    let raw = to_f32(&uniform(&mut rng(8), windows * len, -3.0, 3.0));
    // Reference: standardise by hand, run the network, de-standardise.
    let nz = &ck.normalization;
    let standard: Vec<f32> = raw
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let row = (i / t) % (n * f);
            ((v as f64 - nz.feature_mean[row / f][row % f]) / nz.feature_std[row / f][row % f])
                as f32
        })
        .collect();
    let net = Network::for_inference(&g, c, &ck.graph, windows).unwrap();
    net.load_parameters(&g, &ck.parameters).unwrap();
    let y = net.predict(&g, &standard).unwrap();
    let expected: Vec<[f64; 6]> = (0..windows)
        .map(|w| std::array::from_fn(|m| y[w * 6 + m] as f64 * nz.label_std[m] + nz.label_mean[m]))
        .collect();
    let tol: [f64; 6] = std::array::from_fn(|m| 1e-5 * nz.label_std[m]);

    // On lavapipe `new` runs single windows natively; `Device` forces the WGSL path;
    // `native` has no device at all.
    let auto = Predictor::new(g.clone(), &ck, 2).unwrap();
    assert_eq!(
        auto.backend(),
        if g.is_software() {
            Backend::Native
        } else {
            Backend::Device
        }
    );
    let forced = Predictor::with_backend(g.clone(), &ck, 2, Backend::Device).unwrap();
    assert_eq!(forced.backend(), Backend::Device);
    let native = Predictor::native(&ck).unwrap();
    assert_eq!((native.backend(), native.capacity()), (Backend::Native, 1));
    for (mode, p) in [("auto", auto), ("device", forced), ("native", native)] {
        check_predictor(&g, mode, p, &raw, &expected, (n, f, t), &tol);
    }
}

/// Every way of calling `p` on `raw` (predict, predict_batch, push after unrelated
/// steps, reset) gives `expected` within `tol` per output, and no call creates a pipeline.
fn check_predictor(
    g: &iastgcn::gpu::Gpu,
    mode: &str,
    mut p: Predictor,
    raw: &[f32],
    expected: &[[f64; 6]],
    (n, f, t): (usize, usize, usize),
    tol: &[f64; 6],
) {
    let close = |a: &[f64; 6], b: &[f64; 6], what: &str| {
        for m in 0..6 {
            assert!(
                (a[m] - b[m]).abs() <= tol[m],
                "{mode}: {what}: output {m}: {} vs {}",
                a[m],
                b[m]
            );
        }
    };
    let len = n * f * t;
    let windows = expected.len();
    let pipelines = g.pipeline_count();
    for w in 0..windows {
        let r = p.predict(&raw[w * len..][..len]).unwrap();
        close(&r, &expected[w], &format!("predict window {w}"));
    }
    let mut out = Vec::new();
    p.predict_batch(raw, iastgcn::model::Features::Raw, &mut out)
        .unwrap();
    assert_eq!(out.len(), windows);
    for w in 0..windows {
        close(&out[w], &expected[w], &format!("predict_batch window {w}"));
    }
    // Push the steps of window 3 one at a time, after some unrelated steps.
    let window = &raw[3 * len..][..len];
    let step = |k: usize| -> Vec<f32> { (0..n * f).map(|row| window[row * t + k]).collect() };
    for k in 0..7 {
        p.push(&step(k)).unwrap();
    }
    let mut last = None;
    for k in 0..t {
        last = p.push(&step(k)).unwrap();
    }
    close(&last.expect("a full ring predicts"), &expected[3], "push");
    p.reset();
    assert!(
        p.push(&step(0)).unwrap().is_none(),
        "a reset ring waits for T steps"
    );
    assert_eq!(
        g.pipeline_count(),
        pipelines,
        "a predictor call created a pipeline"
    );
    let err = p.predict(&raw[..len - 1]).unwrap_err().to_string();
    assert!(err.contains("window"), "{err}");
}

#[test]
fn cli_init_and_forward_round_trip() {
    let exe = env!("CARGO_BIN_EXE_iastgcn");
    let config = temp("small.toml");
    std::fs::write(
        &config,
        "[model]\nvariant = \"iastgcn-t\"\nwindow = 16\nchannels = 8\nblocks = 2\n",
    )
    .unwrap();
    let model = temp("cli.safetensors");
    let status = std::process::Command::new(exe)
        .args(["init", "--seed", "3", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&model)
        .status()
        .unwrap();
    assert!(status.success());
    let ck = Checkpoint::load(&model).unwrap();
    assert_eq!(ck.config.variant, Variant::PlainTemporal);
    assert_eq!(ck.parameters, Parameters::init(&ck.config, 3));

    let b = 3;
    let x = to_f32(&uniform(&mut rng(4), b * 14 * 3 * 16, -1.0, 1.0));
    let input = temp("x.safetensors");
    let view = TensorView::new(Dtype::F32, vec![b, 14, 3, 16], bytemuck::cast_slice(&x)).unwrap();
    std::fs::write(&input, safetensors::serialize([("x", view)], None).unwrap()).unwrap();
    let out = temp("y.safetensors");
    let status = std::process::Command::new(exe)
        .args(["forward", "--batch", "2", "--model"])
        .arg(&model)
        .arg("--input")
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let bytes = std::fs::read(&out).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let y = st.tensor("y").unwrap();
    assert_eq!(y.shape(), &[b, 6]);
    let got: Vec<f32> = bytemuck::pod_collect_to_vec(y.data());
    let g = gpu();
    let net = Network::for_inference(&g, &ck.config, &ck.graph, b).unwrap();
    net.load_parameters(&g, &ck.parameters).unwrap();
    assert_eq!(
        got,
        net.predict(&g, &x).unwrap(),
        "CLI forward (2 per submit) vs one batch of 3"
    );

    // A wrong input shape is refused with the expected shape in the message.
    let view = TensorView::new(
        Dtype::F32,
        vec![1, 14, 3, 15],
        &bytemuck::cast_slice(&x)[..14 * 3 * 15 * 4],
    )
    .unwrap();
    std::fs::write(&input, safetensors::serialize([("x", view)], None).unwrap()).unwrap();
    let output = std::process::Command::new(exe)
        .args(["forward", "--model"])
        .arg(&model)
        .arg("--input")
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!output.status.success());
    let msg = String::from_utf8_lossy(&output.stderr);
    assert!(msg.contains("expected [B, 14, 3, 16]"), "{msg}");
}

#[test]
fn interop_init_and_forward_from_the_library() {
    let config = temp("interop.toml");
    std::fs::write(
        &config,
        "[model]\nvariant = \"iastgcn-a\"\nwindow = 16\nchannels = 8\nblocks = 2\n",
    )
    .unwrap();
    let ck = interop::init(Some(&config), Some(Variant::PlainTemporal), None, 5).unwrap();
    assert_eq!(
        ck.config.variant,
        Variant::PlainTemporal,
        "the override wins"
    );
    assert_eq!(ck.config.window, 16);
    assert_eq!(ck.parameters, Parameters::init(&ck.config, 5));
    assert_eq!(ck.normalization, Normalization::identity(&ck.config));
    assert_eq!(ck.graph, Graph::default_asset());
    let paper = interop::init(None, None, None, 1).unwrap();
    assert_eq!(paper.config, ModelConfig::default());

    // y is the network's output in standardised label space, whatever the batch.
    let b = 5;
    let x = to_f32(&uniform(&mut rng(6), b * 14 * 3 * 16, -1.0, 1.0));
    let g = gpu();
    let net = Network::for_inference(&g, &ck.config, &ck.graph, b).unwrap();
    net.load_parameters(&g, &ck.parameters).unwrap();
    let want = net.predict(&g, &x).unwrap();
    assert_eq!(interop::forward_windows(&g, &ck, &x, 2).unwrap(), want);

    let model = temp("interop.safetensors");
    ck.save(&model).unwrap();
    let input = temp("interop-x.safetensors");
    interop::write_tensor(&input, "x", &[b, 14, 3, 16], &x).unwrap();
    let out = temp("interop-y.safetensors");
    let done = interop::forward(&g, &model, &input, &out, 3).unwrap();
    assert_eq!(
        done,
        interop::Forwarded {
            windows: b,
            outputs: 6,
            variant: Variant::PlainTemporal
        }
    );
    let (shape, y) = interop::read_tensor(&out, "y").unwrap();
    assert_eq!(shape, [b, 6]);
    assert_eq!(y, want);

    // Errors are typed and name the file and the tensor.
    let tensor_error = |e: Error| match e.find::<interop::TensorFileError>() {
        Some(e) => (e.path.clone(), e.tensor.clone(), e.message.clone()),
        None => panic!("not a tensor file error: {e}"),
    };
    let (path, tensor, message) = tensor_error(interop::read_tensor(&out, "x").unwrap_err());
    assert_eq!((path, tensor.as_deref()), (out.clone(), Some("x")));
    assert!(message.contains("found: y"), "{message}");
    let mut bad = x.clone();
    bad[7] = f32::NAN;
    interop::write_tensor(&input, "x", &[b, 14, 3, 16], &bad).unwrap();
    let err = interop::forward(&g, &model, &input, &out, 3).unwrap_err();
    let text = err.to_string();
    let (path, tensor, message) = tensor_error(err);
    assert_eq!((path, tensor.as_deref()), (input.clone(), Some("x")));
    assert!(message.contains("element 7 is NaN"), "{text}");
    assert!(
        text.contains("interop-x.safetensors: tensor x: element 7"),
        "{text}"
    );
    let err = interop::forward(&g, &model, &input, &out, 0).unwrap_err();
    // The library names the setting (the command line prints it as --batch).
    assert!(
        err.to_string()
            .starts_with("predict.batch: at least 1 window per batch, got 0"),
        "{err}"
    );
    // No window at all: the file and tensor are named.
    interop::write_tensor(&input, "x", &[0, 14, 3, 16], &[]).unwrap();
    let err = interop::forward(&g, &model, &input, &out, 3).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("interop-x.safetensors: tensor x") && text.contains("B = 0"),
        "{text}"
    );
    let missing = temp("no-such-file.safetensors");
    let err = interop::forward(&g, &model, &missing, &out, 3).unwrap_err();
    assert!(
        matches!(err, Error::Io { ref path, .. } if *path == missing),
        "{err}"
    );
    let graph = temp("interop-graph.toml");
    std::fs::write(&graph, "not a graph").unwrap();
    let err = interop::init(None, None, Some(&graph), 1).unwrap_err();
    assert!(err.to_string().contains("interop-graph.toml"), "{err}");
}

#[test]
fn a_lost_device_is_an_error_and_the_predictor_rebuilds_itself() {
    let g = Arc::new(gpu());
    let ck = checkpoint(Variant::Iastgcn, 7);
    let c = &ck.config;
    let window = to_f32(&uniform(
        &mut rng(9),
        c.nodes * c.features * c.window,
        -3.0,
        3.0,
    ));
    let mut p = Predictor::with_backend(g.clone(), &ck, 2, Backend::Device).unwrap();
    let before = p.predict(&window).unwrap();
    assert!(!p.is_lost());

    // What a driver reset or a removed GPU does: the device goes away under us.
    g.device().destroy();
    let err = p.predict(&window).unwrap_err();
    assert!(
        matches!(&err, ModelError::Gpu(GpuError::DeviceLost { .. })),
        "not a device loss: {err}"
    );
    assert!(err.to_string().contains("lost"), "{err}");
    assert!(p.is_lost());

    p.rebuild().unwrap();
    assert!(!p.is_lost());
    assert_eq!(
        p.predict(&window).unwrap(),
        before,
        "same weights, same answer"
    );
}

#[test]
fn a_batch_beyond_the_adapter_names_the_limit_before_allocating() {
    let g = Arc::new(gpu());
    let ck = checkpoint(Variant::Iastgcn, 7);
    let limit = g.limits().max_storage_buffer_binding_size;
    // Enough windows that the input tensor alone exceeds one binding.
    let c = &ck.config;
    let capacity = (limit / (4 * (c.nodes * c.features * c.window) as u64) + 1) as usize;
    let err = match Predictor::with_backend(g, &ck, capacity, Backend::Device) {
        Ok(_) => panic!("{capacity} windows per submit were accepted"),
        Err(e) => e,
    };
    assert!(
        matches!(&err, ModelError::Gpu(GpuError::TooLarge { .. })),
        "{err}"
    );
    let text = err.to_string();
    assert!(text.contains("this adapter allows"), "{text}");
}
