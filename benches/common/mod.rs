//! What the whole-network benchmarks share: the baseline product, the shapes and a
//! network with random parameters and data.

use iastgcn::gpu::{Dispatch, Gpu};
use iastgcn::graph::Graph;
use iastgcn::model::{ModelConfig, Network, Parameters};
use iastgcn::ops::matmul::Matmul;
use iastgcn::ops::Accumulate;
use iastgcn::testing::{rng, to_f32, uniform};

/// The paper shape's temporal convolution, `[64, 192] · [192, 100]` for each of
/// B·N = 896 rows with the weight shared: the best GFLOP/s the project's matmul reaches
/// (see benches/matmul.rs), the baseline every ratio is quoted against. The dispatch
/// keeps its random operands alive.
pub fn baseline(gpu: &Gpu) -> (Matmul, Dispatch) {
    let mm = Matmul::new(64, 100, 192).batched(896).share_a(true);
    let mut g = rng(1);
    let mut upload = |name: &str, len: usize| {
        gpu.upload(name, &[len], &to_f32(&uniform(&mut g, len, -1.0, 1.0)))
            .unwrap()
    };
    let (a, b, c) = (
        upload("a", mm.a_len()),
        upload("b", mm.b_len()),
        upload("c", mm.c_len()),
    );
    let d = mm.forward(gpu, &a, &b, &c, Accumulate::Overwrite).unwrap();
    (mm, d)
}

/// The small shape: C 16, T 48, L 3.
pub fn small_config() -> ModelConfig {
    ModelConfig {
        channels: 16,
        window: 48,
        blocks: 3,
        ..ModelConfig::default()
    }
}

/// A network at `batch` with He-initialised parameters and random inputs and targets.
pub fn network(gpu: &Gpu, config: &ModelConfig, batch: usize) -> Network {
    let graph = Graph::default_asset();
    let net = Network::new(gpu, config, &graph, batch, 7).unwrap();
    net.load_parameters(gpu, &Parameters::init(config, 1))
        .unwrap();
    let mut g = rng(2);
    let x = uniform(&mut g, net.input.numel(), -1.0, 1.0);
    let y = uniform(&mut g, net.target.numel(), -1.0, 1.0);
    gpu.write(&net.input, &to_f32(&x)).unwrap();
    gpu.write(&net.target, &to_f32(&y)).unwrap();
    net.set_step(gpu, 1).unwrap();
    net
}
