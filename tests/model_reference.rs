//! The f64 reference of the whole network (`model::reference`): its hand-written backward
//! against central differences of `loss(forward(..))` for every parameter tensor and the
//! input, in all four variants, with and without dropout; batch independence, causality
//! of the attention-free blocks, the dropout masks and the loss of eq. 39.
//!
//! One file past 600 lines on purpose: half of it is the last test, docs/model.md's forward
//! transcribed index by index in one piece to be read against the document, and each file
//! in tests/ is one more test binary to build and link.

use iastgcn::graph::Graph;
use iastgcn::model::block::residual_layer_norm::dropout_kernel::keep;
use iastgcn::model::reference::{backward, forward, loss, DropoutStep, Loss, Tape};
use iastgcn::model::{graph_basis, Init, ModelConfig, ParamSpec, Parameters, Variant};
use iastgcn::testing::{compare, rng, uniform, Tolerance, Worst};
use nalgebra::{DMatrix, DVector};
use rand::seq::index::sample;

/// Small shapes with the real 14-node graph: B = 2, F = 3, T = 16, C = 4, L = 2, K = 3.
const BATCH: usize = 2;

/// A network, a batch and its labels.
struct Case {
    config: ModelConfig,
    basis: Vec<f64>,
    specs: Vec<ParamSpec>,
    params: Vec<Vec<f64>>,
    x: Vec<f64>,
    y: Vec<f64>,
}

/// Non-default loss weights so that both terms of eq. 39 are exercised.
const LOSS: Loss = Loss {
    attitude_penalty: 1.7,
    weight_decay: 3e-3,
};

/// He-initialised parameters, with the zero/one-initialised ones (biases, be, bs, θ,
/// ln.*) moved off their initial values so that their gradients are generic.
fn case(variant: Variant, seed: u64) -> Case {
    let config = ModelConfig::gradient_check(variant);
    let graph = Graph::default_asset();
    assert_eq!(graph.len(), config.nodes);
    let basis = graph_basis(&graph, &config);
    let init = Parameters::init(&config, seed);
    let mut r = rng(seed + 1000);
    let params = init
        .specs
        .iter()
        .zip(&init.values)
        .map(|(s, v)| {
            let v: Vec<f64> = v.iter().map(|&w| w as f64).collect();
            match s.init {
                Init::HeUniform { .. } => v,
                Init::Zeros => uniform(&mut r, v.len(), -0.3, 0.3),
                Init::Ones => uniform(&mut r, v.len(), 0.7, 1.3),
            }
        })
        .collect();
    let x = uniform(
        &mut r,
        BATCH * config.nodes * config.features * config.window,
        -1.0,
        1.0,
    );
    let y = uniform(&mut r, BATCH * config.outputs, -1.0, 1.0);
    Case {
        config,
        basis,
        specs: init.specs,
        params,
        x,
        y,
    }
}

impl Case {
    fn forward(&self, params: &[Vec<f64>], x: &[f64], dropout: Option<DropoutStep>) -> Tape {
        forward(
            &self.config,
            &self.basis,
            &self.specs,
            params,
            x,
            BATCH,
            dropout,
        )
    }

    /// The loss and the ReLU pattern at (params, x).
    fn eval(
        &self,
        params: &[Vec<f64>],
        x: &[f64],
        dropout: Option<DropoutStep>,
    ) -> (f64, Vec<bool>) {
        let tape = self.forward(params, x, dropout);
        let l = loss(
            &self.config,
            &self.specs,
            params,
            &tape.output,
            &self.y,
            BATCH,
            &LOSS,
        );
        (l, tape.relu_pattern())
    }
}

/// Central differences with step `H`. The truncation error ~H²·f''' is the larger one
/// (LayerNorm over C = 4 channels is sharply curved: at H = 1e-5 it reaches a relative
/// 8e-6, scaling as H²); at H = 1e-6 it is ~1e-7 relative, and rounding ~1e-16·|ℒ|/H
/// ~1e-9 absolute.
const H: f64 = 1e-6;
const TOL: Tolerance = Tolerance::new(1e-7, 1e-5);

/// Tensors up to this size are checked in full, larger ones on a seeded random subset.
const FULL: usize = 256;
const SUBSET: usize = 64;

struct Checked {
    worst: Worst,
    elements: usize,
    /// Elements whose ±H evaluations changed the ReLU pattern (a kink between them):
    /// not a derivative, so skipped; counted and bounded.
    kinks: usize,
}

/// Compares `analytic` with central differences of `eval` at `point` on the elements
/// `picks`, skipping those whose finite difference straddles a ReLU kink.
fn fd_check(
    what: &str,
    analytic: &[f64],
    point: &[f64],
    picks: &[usize],
    pattern: &[bool],
    eval: impl Fn(&[f64]) -> (f64, Vec<bool>),
) -> Checked {
    assert_eq!(analytic.len(), point.len(), "{what}: gradient size");
    let (mut got, mut want, mut kinks) = (Vec::new(), Vec::new(), 0);
    let mut p = point.to_vec();
    for &i in picks {
        p[i] = point[i] + H;
        let (up, pu) = eval(&p);
        p[i] = point[i] - H;
        let (down, pd) = eval(&p);
        p[i] = point[i];
        if pu != pattern || pd != pattern {
            kinks += 1;
            continue;
        }
        got.push(analytic[i]);
        want.push((up - down) / (2.0 * H));
    }
    let worst = compare(what, &got, &want, TOL).unwrap_or_else(|e| panic!("{e}"));
    Checked {
        worst,
        elements: got.len(),
        kinks,
    }
}

fn picks(n: usize, seed: u64) -> Vec<usize> {
    if n <= FULL {
        (0..n).collect()
    } else {
        let mut v = sample(&mut rng(seed), n, SUBSET).into_vec();
        v.sort_unstable();
        v
    }
}

/// Every parameter tensor and x of `variant`, with dropout off and on; prints the worst
/// ratio (error / tolerance) of each (run with `--nocapture` to see it).
fn check_variant(variant: Variant) {
    let c = case(variant, 7);
    for dropout in [
        None,
        Some(DropoutStep {
            seed: 0xdead_beef,
            step: 3,
        }),
    ] {
        let tape = c.forward(&c.params, &c.x, dropout);
        let pattern = tape.relu_pattern();
        let (grads, dx) = backward(
            &c.config, &c.basis, &c.specs, &c.params, &tape, &c.y, BATCH, &LOSS,
        );
        assert_eq!(grads.len(), c.specs.len());
        let (mut elements, mut kinks, mut worst_ratio) = (0, 0, 0.0f64);
        let mut report = |what: &str, analytic: &[f64], ch: Checked| {
            // A check of zeros against zeros would prove nothing.
            let max = analytic.iter().fold(0.0f64, |m, g| m.max(g.abs()));
            assert!(max > 1e-6, "{what}: gradient is ~0 (max {max:.1e})");
            worst_ratio = worst_ratio.max(ch.worst.ratio);
            elements += ch.elements;
            kinks += ch.kinks;
        };
        for (k, spec) in c.specs.iter().enumerate() {
            let what = format!("{variant} dropout={} {}", dropout.is_some(), spec.name);
            let ch = fd_check(
                &what,
                &grads[k],
                &c.params[k],
                &picks(spec.numel(), k as u64),
                &pattern,
                |v| {
                    let mut p = c.params.clone();
                    p[k] = v.to_vec();
                    c.eval(&p, &c.x, dropout)
                },
            );
            report(&what, &grads[k], ch);
        }
        let what = format!("{variant} dropout={} x", dropout.is_some());
        let ch = fd_check(&what, &dx, &c.x, &picks(c.x.len(), 999), &pattern, |v| {
            c.eval(&c.params, v, dropout)
        });
        report(&what, &dx, ch);
        println!(
            "{variant} dropout={}: {elements} elements checked, {kinks} skipped at ReLU kinks, worst ratio {worst_ratio:.3}",
            dropout.is_some()
        );
        // Kinks are rare (a pre-activation within ~H of zero); many would mean a bug.
        assert!(
            kinks * 20 <= elements,
            "{variant}: {kinks} of {elements} at kinks"
        );
    }
}

#[test]
fn gradients_iastgcn() {
    check_variant(Variant::Iastgcn);
}

#[test]
fn gradients_iastgcn_a() {
    check_variant(Variant::NoAttention);
}

#[test]
fn gradients_iastgcn_t() {
    check_variant(Variant::PlainTemporal);
}

#[test]
fn gradients_iastgcn_s() {
    check_variant(Variant::Chebyshev);
}

#[test]
fn gradients_st_gat() {
    check_variant(Variant::StGat);
}

/// Changing x of one batch item at the last step changes that item's output only, and
/// the evaluation forward is bit-for-bit deterministic.
#[test]
fn batch_items_are_independent_and_eval_is_deterministic() {
    for variant in Variant::IASTGCN {
        let c = case(variant, 11);
        let base = c.forward(&c.params, &c.x, None);
        let again = c.forward(&c.params, &c.x, None);
        assert_eq!(base.output, again.output, "{variant}: not deterministic");
        let (f, t) = (c.config.features, c.config.window);
        let mut x = c.x.clone();
        // Item 1, every node and feature, last step.
        for n in 0..c.config.nodes {
            for k in 0..f {
                x[((c.config.nodes + n) * f + k) * t + t - 1] += 0.5;
            }
        }
        let moved = c.forward(&c.params, &x, None);
        let o = c.config.outputs;
        assert_eq!(
            base.output[..o],
            moved.output[..o],
            "{variant}: item 0 changed"
        );
        assert!(
            base.output[o..]
                .iter()
                .zip(&moved.output[o..])
                .all(|(a, b)| a != b),
            "{variant}: item 1 did not change"
        );
    }
}

/// Without attention (the only step that mixes time both ways) every block is causal:
/// changing x at step t0 leaves all block outputs before t0 unchanged, bit for bit.
#[test]
fn attention_free_blocks_are_causal() {
    let c = case(Variant::NoAttention, 5);
    let (nn, f, t) = (c.config.nodes, c.config.features, c.config.window);
    let t0 = t / 2;
    let mut x = c.x.clone();
    for row in 0..BATCH * nn * f {
        x[row * t + t0] -= 0.7;
    }
    let dropout = Some(DropoutStep { seed: 1, step: 2 });
    let (a, b) = (
        c.forward(&c.params, &c.x, dropout),
        c.forward(&c.params, &x, dropout),
    );
    for (l, (ba, bb)) in a.blocks.iter().zip(&b.blocks).enumerate() {
        let rows = ba.output.chunks_exact(t).zip(bb.output.chunks_exact(t));
        let mut later_changed = false;
        for (ra, rb) in rows {
            assert_eq!(ra[..t0], rb[..t0], "block {l} output changed before t0");
            later_changed |= ra[t0..] != rb[t0..];
        }
        assert!(later_changed, "block {l} output did not change at all");
    }
}

/// Block l's mask is `keep(Dropout { seed + l, p }, step, i)` and kept values are scaled
/// by 1/(1−p): block 0 with dropout equals block 0 without, masked and scaled.
#[test]
fn dropout_uses_the_block_seeds() {
    let c = case(Variant::Iastgcn, 3);
    let ds = DropoutStep { seed: 42, step: 9 };
    let on = c.forward(&c.params, &c.x, Some(ds));
    let off = c.forward(&c.params, &c.x, None);
    let scale = 1.0 / (1.0 - c.config.dropout);
    for (l, block) in on.blocks.iter().enumerate() {
        let m = ds.block(&c.config, BATCH, l);
        assert_eq!(m.seed, 42 + l as u32);
        let mask = block.mask.as_ref().expect("mask");
        assert_eq!(mask.len(), m.n);
        for (i, &k) in mask.iter().enumerate() {
            assert_eq!(k, keep(&m, ds.step, i), "block {l} element {i}");
        }
        let kept = mask.iter().filter(|&&k| k).count() as f64 / mask.len() as f64;
        assert!((kept - 0.8).abs() < 0.05, "block {l} kept {kept}");
    }
    for (i, (&a, &b)) in on.blocks[0]
        .output
        .iter()
        .zip(&off.blocks[0].output)
        .enumerate()
    {
        let want = if on.blocks[0].mask.as_ref().unwrap()[i] {
            b * scale
        } else {
            0.0
        };
        assert!((a - want).abs() <= 1e-15 * want.abs(), "element {i}");
    }
    assert!(off.blocks.iter().all(|b| b.mask.is_none()));
    assert_ne!(on.output, off.output);
}

/// Eq. 39 by hand: position errors weigh 1, attitude errors P, plus λ·Σ‖W‖² over the
/// decayed parameters only.
#[test]
fn loss_is_eq_39() {
    let c = case(Variant::Iastgcn, 1);
    let output: Vec<f64> = (0..BATCH * 6).map(|i| i as f64 * 0.25).collect();
    let y: Vec<f64> = (0..BATCH * 6).map(|i| 1.0 - i as f64 * 0.5).collect();
    let mut data = 0.0;
    for b in 0..BATCH {
        for m in 0..6 {
            let e = output[b * 6 + m] - y[b * 6 + m];
            data += if m < 3 { e * e } else { 1.7 * e * e };
        }
    }
    let mut decay = 0.0;
    for (s, v) in c.specs.iter().zip(&c.params) {
        let decayed = s.name.ends_with("weight")
            || s.name.ends_with(".W")
            || ["U1", "U2", "U3", "Ve", "W1", "W2", "W3", "Vs"]
                .iter()
                .any(|w| s.name.ends_with(&format!(".{w}")));
        assert_eq!(s.decay, decayed, "{}", s.name);
        if decayed {
            decay += v.iter().map(|w| w * w).sum::<f64>();
        }
    }
    let want = data / BATCH as f64 + 3e-3 * decay;
    let got = loss(&c.config, &c.specs, &c.params, &output, &y, BATCH, &LOSS);
    assert!((got - want).abs() <= 1e-12 * want.abs(), "{got} vs {want}");
}

/// docs/model.md's formulas written out index by index (slow, but a direct transcription),
/// against every block of the tape, in every variant, with dropout: catches what finite
/// differences cannot (a transposed index, the softmax axis, the kernel's lag direction,
/// Ψ's construction), since the backward is only checked against this same forward.
#[test]
fn forward_follows_model_md_literally() {
    let sigmoid = |v: f64| 1.0 / (1.0 + (-v).exp());
    let close = |what: String, got: &[f64], want: &[f64]| {
        compare(&what, got, want, Tolerance::new(1e-12, 1e-10)).unwrap_or_else(|e| panic!("{e}"));
    };
    let spectral = Graph::default_asset().spectral();
    for variant in Variant::IASTGCN {
        let c = case(variant, 13);
        let ds = DropoutStep { seed: 5, step: 1 };
        let tape = c.forward(&c.params, &c.x, Some(ds));
        let cfg = &c.config;
        let (nb, nn, nc, nt, nk) = (BATCH, cfg.nodes, cfg.channels, cfg.window, cfg.kernel);
        let p = |name: String| -> &[f64] {
            &c.params[c.specs.iter().position(|s| s.name == name).unwrap()]
        };
        for l in 0..cfg.blocks {
            let ci = if l == 0 { cfg.features } else { nc };
            let x: &[f64] = if l == 0 {
                &c.x
            } else {
                &tape.blocks[l - 1].output
            };
            let bt = &tape.blocks[l];
            let q = |s: &str| p(format!("blocks.{l}.{s}"));
            let xi = |b: usize, n: usize, ch: usize, t: usize| ((b * nn + n) * ci + ch) * nt + t;
            let hi = |b: usize, n: usize, ch: usize, t: usize| ((b * nn + n) * nc + ch) * nt + t;
            let what = |s: &str| format!("{variant} block {l} {s}");

            let xs: Vec<f64> = if variant == Variant::NoAttention {
                assert!(bt.temporal.is_none() && bt.spatial.is_none());
                x.to_vec()
            } else {
                // Step 1: temporal attention.
                let (u1, u2, u3, be, ve) = (
                    q("tat.U1"),
                    q("tat.U2"),
                    q("tat.U3"),
                    q("tat.be"),
                    q("tat.Ve"),
                );
                let mut lhs = vec![0.0; nb * nt * nn]; // [B,T,N]
                let mut rhs = vec![0.0; nb * nn * nt]; // [B,N,T]
                for b in 0..nb {
                    for t in 0..nt {
                        for m in 0..nn {
                            lhs[(b * nt + t) * nn + m] = (0..ci)
                                .map(|ch| {
                                    (0..nn).map(|n| x[xi(b, n, ch, t)] * u1[n]).sum::<f64>()
                                        * u2[ch * nn + m]
                                })
                                .sum();
                        }
                    }
                    for n in 0..nn {
                        for t in 0..nt {
                            rhs[(b * nn + n) * nt + t] =
                                (0..ci).map(|ch| u3[ch] * x[xi(b, n, ch, t)]).sum();
                        }
                    }
                }
                let tt = |b: usize, t: usize, u: usize| (b * nt + t) * nt + u;
                let mut pm = vec![0.0; nb * nt * nt];
                for b in 0..nb {
                    for t in 0..nt {
                        for u in 0..nt {
                            pm[tt(b, t, u)] = (0..nn)
                                .map(|n| lhs[(b * nt + t) * nn + n] * rhs[(b * nn + n) * nt + u])
                                .sum();
                        }
                    }
                }
                let mut e = vec![0.0; nb * nt * nt];
                for b in 0..nb {
                    for t in 0..nt {
                        for u in 0..nt {
                            e[tt(b, t, u)] = (0..nt)
                                .map(|k| ve[t * nt + k] * sigmoid(pm[tt(b, k, u)] + be[k * nt + u]))
                                .sum();
                        }
                    }
                }
                let mut ep = vec![0.0; nb * nt * nt];
                for b in 0..nb {
                    for t in 0..nt {
                        for u in 0..nt {
                            let z: f64 = (0..nt).map(|v| e[tt(b, v, u)].exp()).sum();
                            ep[tt(b, t, u)] = e[tt(b, t, u)].exp() / z;
                        }
                    }
                }
                let ta = bt.temporal.as_ref().expect("temporal tape");
                close(what("E'"), &ta.weights, &ep);
                let mut xt = vec![0.0; x.len()];
                for b in 0..nb {
                    for n in 0..nn {
                        for ch in 0..ci {
                            for u in 0..nt {
                                xt[xi(b, n, ch, u)] = (0..nt)
                                    .map(|t| {
                                        let id = if t == u { 1.0 } else { 0.0 };
                                        x[xi(b, n, ch, t)] * (ep[tt(b, t, u)] + id)
                                    })
                                    .sum();
                            }
                        }
                    }
                }
                close(what("X_t"), &ta.output, &xt);

                // Step 2: spatial attention.
                let (w1, w2, w3, bs, vs) = (
                    q("sat.W1"),
                    q("sat.W2"),
                    q("sat.W3"),
                    q("sat.bs"),
                    q("sat.Vs"),
                );
                let mut lhs = vec![0.0; nb * nn * nt]; // [B,N,T]
                let mut rhs = vec![0.0; nb * nt * nn]; // [B,T,N]
                for b in 0..nb {
                    for n in 0..nn {
                        for t in 0..nt {
                            lhs[(b * nn + n) * nt + t] = (0..ci)
                                .map(|ch| {
                                    (0..nt).map(|u| xt[xi(b, n, ch, u)] * w1[u]).sum::<f64>()
                                        * w2[ch * nt + t]
                                })
                                .sum();
                        }
                    }
                    for t in 0..nt {
                        for m in 0..nn {
                            rhs[(b * nt + t) * nn + m] =
                                (0..ci).map(|ch| w3[ch] * xt[xi(b, m, ch, t)]).sum();
                        }
                    }
                }
                let nm = |b: usize, i: usize, j: usize| (b * nn + i) * nn + j;
                let mut pm = vec![0.0; nb * nn * nn];
                for b in 0..nb {
                    for n in 0..nn {
                        for m in 0..nn {
                            pm[nm(b, n, m)] = (0..nt)
                                .map(|t| lhs[(b * nn + n) * nt + t] * rhs[(b * nt + t) * nn + m])
                                .sum();
                        }
                    }
                }
                let mut s = vec![0.0; nb * nn * nn];
                for b in 0..nb {
                    for i in 0..nn {
                        for j in 0..nn {
                            s[nm(b, i, j)] = (0..nn)
                                .map(|k| vs[i * nn + k] * sigmoid(pm[nm(b, k, j)] + bs[k * nn + j]))
                                .sum();
                        }
                    }
                }
                let mut sp = vec![0.0; nb * nn * nn];
                for b in 0..nb {
                    for i in 0..nn {
                        let z: f64 = (0..nn).map(|k| s[nm(b, i, k)].exp()).sum();
                        for j in 0..nn {
                            sp[nm(b, i, j)] = s[nm(b, i, j)].exp() / z;
                        }
                    }
                }
                let sa = bt.spatial.as_ref().expect("spatial tape");
                close(what("S'"), &sa.weights, &sp);
                let mut xs = vec![0.0; x.len()];
                for b in 0..nb {
                    for i in 0..nn {
                        for ch in 0..ci {
                            for t in 0..nt {
                                xs[xi(b, i, ch, t)] = (0..nn)
                                    .map(|j| {
                                        let id = if i == j { 1.0 } else { 0.0 };
                                        (sp[nm(b, i, j)] + id) * xt[xi(b, j, ch, t)]
                                    })
                                    .sum();
                            }
                        }
                    }
                }
                close(what("X_s"), &sa.output, &xs);
                xs
            };

            // Step 3: Ψ from the graph itself (not from `graph_basis`), then Z.
            let theta = q("gwc.theta");
            let psi = if variant == Variant::Chebyshev {
                let terms = spectral.chebyshev(cfg.chebyshev_order);
                assert_eq!(theta.len(), terms.len());
                terms
                    .iter()
                    .zip(theta)
                    .fold(DMatrix::zeros(nn, nn), |acc, (tk, &th)| acc + tk * th)
            } else {
                let s = cfg.scale;
                spectral.wavelet(s)
                    * DMatrix::from_diagonal(&DVector::from_column_slice(theta))
                    * spectral.wavelet_inverse(s)
            };
            let w = q("gwc.W");
            let mut z = vec![0.0; nb * nn * nc * nt];
            for b in 0..nb {
                for i in 0..nn {
                    for o in 0..nc {
                        for t in 0..nt {
                            let v: f64 = (0..nn)
                                .map(|j| {
                                    psi[(i, j)]
                                        * (0..ci)
                                            .map(|ch| xs[xi(b, j, ch, t)] * w[ch * nc + o])
                                            .sum::<f64>()
                                })
                                .sum();
                            z[hi(b, i, o, t)] = v.max(0.0);
                        }
                    }
                }
            }
            close(what("Z"), &bt.z, &z);

            // Step 4: kernel index k is the lag, d_l = 2^l (0-based l), 1 in iastgcn-t.
            let dil = if variant == Variant::PlainTemporal {
                1
            } else {
                1 << l
            };
            let conv = |wt: &[f64], bias: &[f64]| {
                let mut g = vec![0.0; z.len()];
                for b in 0..nb {
                    for n in 0..nn {
                        for o in 0..nc {
                            for t in 0..nt {
                                let mut v = bias[o];
                                for ch in 0..nc {
                                    for k in 0..nk {
                                        if t >= dil * k {
                                            v += wt[(o * nc + ch) * nk + k]
                                                * z[hi(b, n, ch, t - dil * k)];
                                        }
                                    }
                                }
                                g[hi(b, n, o, t)] = v;
                            }
                        }
                    }
                }
                g
            };
            let gf = conv(q("tcn.filter.weight"), q("tcn.filter.bias"));
            let h: Vec<f64> = if variant == Variant::PlainTemporal {
                assert!(bt.gate.is_none());
                gf.iter().map(|&v| v.max(0.0)).collect()
            } else {
                let gg = conv(q("tcn.gate.weight"), q("tcn.gate.bias"));
                gf.iter()
                    .zip(&gg)
                    .map(|(&f, &g)| f.tanh() * sigmoid(g))
                    .collect()
            };

            // Steps 5–7.
            let (rw, rb, gamma, beta) =
                (q("res.weight"), q("res.bias"), q("ln.gamma"), q("ln.beta"));
            let mut a = vec![0.0; z.len()];
            for b in 0..nb {
                for n in 0..nn {
                    for o in 0..nc {
                        for t in 0..nt {
                            let r: f64 = rb[o]
                                + (0..ci)
                                    .map(|ch| rw[o * ci + ch] * x[xi(b, n, ch, t)])
                                    .sum::<f64>();
                            a[hi(b, n, o, t)] = (h[hi(b, n, o, t)] + r).max(0.0);
                        }
                    }
                }
            }
            close(what("ReLU(H + R)"), &bt.act, &a);
            let mask = ds.block(cfg, nb, l);
            // ε as the engine holds it: an f32 (the device's, the native path's and the
            // LayerNorm op's reference's).
            let eps = cfg.eps as f32 as f64;
            let mut out = vec![0.0; z.len()];
            for b in 0..nb {
                for n in 0..nn {
                    for t in 0..nt {
                        let mu = (0..nc).map(|o| a[hi(b, n, o, t)]).sum::<f64>() / nc as f64;
                        let var = (0..nc)
                            .map(|o| (a[hi(b, n, o, t)] - mu).powi(2))
                            .sum::<f64>()
                            / nc as f64;
                        for o in 0..nc {
                            let i = hi(b, n, o, t);
                            let y = gamma[o] * (a[i] - mu) / (var + eps).sqrt() + beta[o];
                            out[i] = if keep(&mask, ds.step, i) {
                                y / (1.0 - cfg.dropout)
                            } else {
                                0.0
                            };
                        }
                    }
                }
            }
            close(what("Y"), &bt.output, &out);
        }

        // Head.
        let (hw, hb) = (p("head.weight".into()), p("head.bias".into()));
        let last = &tape.blocks[cfg.blocks - 1].output;
        let mut yhat = vec![0.0; nb * cfg.outputs];
        for b in 0..nb {
            for o in 0..cfg.outputs {
                yhat[b * cfg.outputs + o] = hb[o]
                    + (0..nn)
                        .flat_map(|n| (0..nc).map(move |ch| (n, ch)))
                        .map(|(n, ch)| {
                            hw[o * nn * nc + n * nc + ch]
                                * last[((b * nn + n) * nc + ch) * nt + nt - 1]
                        })
                        .sum::<f64>();
            }
        }
        close(format!("{variant} ŷ"), &tape.output, &yhat);
    }
}
