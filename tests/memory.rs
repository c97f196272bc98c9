//! Device memory accounting: `Gpu::allocations_during` sees exactly the buffers created
//! inside it, and `model::memory::footprint` reports a network's memory and the largest
//! batch under the adapter's limits.

use iastgcn::graph::Graph;
use iastgcn::model::memory::footprint;
use iastgcn::model::{ModelConfig, Network, Pass, Variant};
use iastgcn::testing::gpu;

#[test]
fn footprint_counts_every_buffer() {
    let g = gpu();
    let graph = Graph::default_asset();
    for variant in [Variant::Iastgcn, Variant::Tgcn, Variant::Mlp] {
        let config = ModelConfig::gradient_check(variant);
        for pass in [Pass::Train, Pass::Inference] {
            let f = footprint(&g, &config, &graph, pass, 5).unwrap();
            let (net, log) = g.allocations_during(|| match pass {
                Pass::Train => Network::new(&g, &config, &graph, 5, 0),
                Pass::Inference => Network::for_inference(&g, &config, &graph, 5),
            });
            let net = net.unwrap();
            assert_eq!(
                log.iter().map(|a| a.bytes).sum::<u64>(),
                f.bytes,
                "{variant} {pass:?}"
            );
            // Each input window is one of the buffers that grow.
            let window = net.input.byte_len() / 5;
            assert!(f.per_window_bytes() > window, "{variant} {pass:?}: {f:?}");
            assert!(f.bytes > f.bytes_at_one, "{f:?}");
        }
    }
    // Outside the closure nothing is recorded; a batch below 2 is refused.
    let (_, log) = g.allocations_during(|| ());
    assert!(log.is_empty());
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let e = footprint(&g, &config, &graph, Pass::Train, 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 2"), "{e}");
}

/// The paper shape's training network at B = 64 fits lavapipe's (or any adapter's)
/// limits, so the largest batch is at least 64.
#[test]
fn paper_shape_fits_batch_64() {
    let g = gpu();
    let config = ModelConfig::default();
    let f = footprint(&g, &config, &Graph::default_asset(), Pass::Train, 64).unwrap();
    assert!(f.max_batch >= 64, "{f:?}");
    assert!(f.largest.1 <= f.limit_bytes, "{f:?}");
}
