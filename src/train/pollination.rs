//! The population search of ANN-BFPA (docs/model.md "Baselines"): a flower-pollination
//! search (Yang, 2012) over the ANN's whole weight vector that picks the starting weights
//! the gradient training then refines. Seeded and reproducible: one ChaCha8 stream from
//! `[train] seed`, candidates scored in order on a fixed sample of training windows.
//!
//! Each generation, every candidate x_i proposes one move and keeps it only if it lowers
//! the loss (greedy selection):
//! - with probability `switch`, global pollination towards the best g*:
//!   x_i + step · L ⊙ (g* − x_i), L a vector of Lévy(1.5) steps (Mantegna's algorithm);
//! - otherwise local pollination: x_i + ε (x_j − x_k), ε ~ U(0, 1), j ≠ k random.
//!
//! The first candidate is the plain He initialisation of the seed, so the search never
//! returns weights that score worse on its sample than the start every other model gets.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::config::TrainConfig;
use super::metrics::window_loss;
use super::trainer::TrainError;
use crate::data::{Dataset, OUTPUTS};
use crate::gpu::{Device, Gpu};
use crate::graph::Graph;
use crate::model::{ModelConfig, NativeForward, Network, Parameters};
use crate::progress::Reporter;

/// The search's settings (docs/model.md "Baselines" gives the defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct Pollination {
    /// Candidates (flowers).
    pub population: usize,
    /// Generations after the initial one.
    pub generations: usize,
    /// Probability of a global (Lévy) move.
    pub switch: f64,
    /// Scale of a global move.
    pub step: f64,
    /// Training windows the loss is measured on (evenly spaced over the training split).
    pub windows: usize,
}

impl Default for Pollination {
    fn default() -> Pollination {
        Pollination {
            population: 20,
            generations: 15,
            switch: 0.8,
            step: 0.1,
            windows: 256,
        }
    }
}

/// What the search found.
#[derive(Clone, Debug)]
pub struct Searched {
    /// The best candidate: the starting weights of the gradient training.
    pub params: Parameters,
    /// The loss (eq. 39's data term, mean per window) of the plain He initialisation.
    pub start_loss: f64,
    /// The loss of the best candidate.
    pub best_loss: f64,
    /// Losses evaluated.
    pub evaluations: usize,
}

/// Lévy(λ = 1.5) step by Mantegna's algorithm: u / |v|^(1/λ), u ~ N(0, σ_u²), v ~ N(0, 1),
/// σ_u = [Γ(1+λ) sin(πλ/2) / (Γ((1+λ)/2) λ 2^((λ−1)/2))]^(1/λ).
fn levy(rng: &mut ChaCha8Rng) -> f64 {
    const LAMBDA: f64 = 1.5;
    // Γ(2.5) = 1.329340…, Γ(1.25) = 0.906402…
    let sigma = (1.329_340_388 * (std::f64::consts::PI * LAMBDA / 2.0).sin()
        / (0.906_402_477 * LAMBDA * 2f64.powf((LAMBDA - 1.0) / 2.0)))
    .powf(1.0 / LAMBDA);
    let u: f64 = StandardNormal.sample(rng);
    let v: f64 = StandardNormal.sample(rng);
    sigma * u / v.abs().powf(1.0 / LAMBDA)
}

/// `template`'s tensors filled, in order, from the concatenated values `flat`.
fn unflatten(template: &Parameters, flat: &[f32]) -> Parameters {
    let mut p = template.clone();
    let mut at = 0;
    for v in &mut p.values {
        let n = v.len();
        v.copy_from_slice(&flat[at..at + n]);
        at += n;
    }
    p
}

/// Where the candidates' forward passes run.
enum ScoreNet<'a> {
    /// The inference schedule for the whole sample on the adapter.
    Device { gpu: &'a Gpu, net: Box<Network> },
    /// The native CPU forward, one window of `window` values at a time (no adapter).
    Native {
        forward: Box<NativeForward>,
        window: usize,
    },
}

/// Scores candidates: the mean per-window loss on a fixed sample of training windows.
struct Scorer<'a> {
    net: ScoreNet<'a>,
    template: Parameters,
    x: Vec<f32>,
    y: Vec<f32>,
    penalty: f64,
}

impl Scorer<'_> {
    fn loss(&mut self, flat: &[f32]) -> Result<f64, TrainError> {
        let params = unflatten(&self.template, flat);
        let out = match &mut self.net {
            ScoreNet::Device { gpu, net } => {
                net.load_parameters(gpu, &params)?;
                net.predict(gpu, &self.x)?
            }
            ScoreNet::Native { forward, window } => {
                forward.set_parameters(&params)?;
                let mut out = vec![0f32; self.y.len()];
                for (x, row) in self.x.chunks(*window).zip(out.chunks_mut(OUTPUTS)) {
                    forward.forward(x, row)?;
                }
                out
            }
        };
        let n = self.y.len() / OUTPUTS;
        let total: f64 = out
            .chunks(OUTPUTS)
            .zip(self.y.chunks(OUTPUTS))
            .map(|(p, y)| window_loss(p, y, self.penalty))
            .sum();
        // A non-finite loss never wins a comparison.
        Ok(if total.is_finite() {
            total / n as f64
        } else {
            f64::INFINITY
        })
    }
}

/// Runs the search for `model` on `data`'s training split, seeded by `train.seed`, the loss
/// weighted by `train.attitude_penalty`.
pub fn pollinate(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    model: &ModelConfig,
    train: &TrainConfig,
    search: &Pollination,
    reporter: &mut dyn Reporter,
) -> Result<Searched, TrainError> {
    let (seed, penalty) = (train.seed, train.attitude_penalty);
    let [train, _, _] = data.split_ranges();
    if train.is_empty() || search.population < 3 || search.windows == 0 {
        return Err(TrainError::Data(
            "the pollination search needs training windows and at least 3 candidates".into(),
        ));
    }
    let count = search.windows.min(train.len());
    let positions: Vec<usize> = (0..count)
        .map(|i| train.start + i * train.len() / count)
        .collect();
    let (mut x, mut y) = (Vec::new(), Vec::new());
    data.gather_into(&positions, &mut x, &mut y);
    let template = Parameters::init(model, seed);
    let net = match device {
        Device::Adapter(gpu) => ScoreNet::Device {
            gpu,
            net: Box::new(Network::for_inference(gpu, model, graph, count)?),
        },
        Device::Native => ScoreNet::Native {
            forward: Box::new(NativeForward::new(model, graph, &template)?),
            window: data.window_len(),
        },
    };
    let mut scorer = Scorer {
        net,
        template,
        x,
        y,
        penalty,
    };
    let flat = |p: &Parameters| p.values.concat();
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x00f1_0e5e_a5c4_u64);
    let mut flowers: Vec<Vec<f32>> = (0..search.population)
        .map(|i| flat(&Parameters::init(model, seed.wrapping_add(i as u64))))
        .collect();
    let total = search.population * (search.generations + 1);
    reporter.begin("ann-bfpa pollination search", total as u64);
    let mut fitness = Vec::with_capacity(search.population);
    for (i, f) in flowers.iter().enumerate() {
        fitness.push(scorer.loss(f)?);
        reporter.update(i as u64 + 1, "");
    }
    let start_loss = fitness[0];
    let best_of = |fit: &[f64]| (0..fit.len()).fold(0, |b, i| if fit[i] < fit[b] { i } else { b });
    let mut best = best_of(&fitness);
    let mut evaluations = search.population;
    for _ in 0..search.generations {
        for i in 0..search.population {
            let candidate: Vec<f32> = if rng.random::<f64>() < search.switch {
                let g = &flowers[best];
                flowers[i]
                    .iter()
                    .zip(g)
                    .map(|(&x, &g)| x + (search.step * levy(&mut rng) * (g - x) as f64) as f32)
                    .collect()
            } else {
                let j = rng.random_range(0..search.population);
                let mut k = rng.random_range(0..search.population - 1);
                if k >= j {
                    k += 1;
                }
                let eps: f64 = rng.random();
                flowers[i]
                    .iter()
                    .zip(&flowers[j])
                    .zip(&flowers[k])
                    .map(|((&x, &a), &b)| x + (eps * (a - b) as f64) as f32)
                    .collect()
            };
            let loss = scorer.loss(&candidate)?;
            evaluations += 1;
            if loss < fitness[i] {
                flowers[i] = candidate;
                fitness[i] = loss;
                if loss < fitness[best] {
                    best = i;
                }
            }
            reporter.update(
                evaluations as u64,
                &format!("best loss {:.4}", fitness[best]),
            );
        }
    }
    reporter.end();
    Ok(Searched {
        params: unflatten(&scorer.template, &flowers[best]),
        start_loss,
        best_loss: fitness[best],
        evaluations,
    })
}
