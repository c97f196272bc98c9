//! The sensor-graph asset: Table II's 14 nodes, a connected structure, and clear errors.

use iastgcn::graph::Graph;

#[test]
fn default_graph_is_table_ii() {
    let g = Graph::default_asset();
    assert_eq!(
        g.nodes,
        [
            "E1", "E2", "E3", "E4", "E5", "E6", "Q1", "Q2", "Q3", "Q4", "Q5", "phiX", "phiY",
            "phiZ"
        ]
    );
    let a = g.adjacency();
    assert_eq!(a, a.transpose());
    assert!((0..14).all(|i| a[(i, i)] == 0.0));
    // Connected: every node reachable from E1.
    let mut seen = [false; 14];
    let mut stack = vec![0];
    while let Some(i) = stack.pop() {
        if !std::mem::replace(&mut seen[i], true) {
            stack.extend((0..14).filter(|&j| a[(i, j)] > 0.0));
        }
    }
    assert!(seen.iter().all(|&s| s), "graph is not connected");
}

#[test]
fn bad_graphs_are_rejected_by_name() {
    let cases = [
        (
            "nodes = [\"A\", \"B\"]\nedges = [[\"A\", \"C\"]]",
            "edge names unknown node \"C\"",
        ),
        (
            "nodes = [\"A\", \"A\"]\nedges = []",
            "node \"A\" is listed twice",
        ),
        (
            "nodes = [\"A\"]\nedges = [[\"A\", \"A\"]]",
            "self loop on node \"A\"",
        ),
        (
            "nodes = [\"A\", \"B\"]\nedges = [[\"A\", \"B\"], [\"B\", \"A\"]]",
            "listed twice",
        ),
        ("nodes = []\nedges = []", "`nodes` is empty"),
        ("nodes = [\"A,B\"]\nedges = []", "without commas"),
        ("nodes = [\"A\"]\nedge = []", "edge"),
    ];
    for (text, want) in cases {
        let err = Graph::parse(text, "g.toml").unwrap_err().to_string();
        assert!(err.starts_with("g.toml: ") && err.contains(want), "{err}");
    }
}

fn chain(n: usize, ring: bool) -> Graph {
    let nodes: Vec<String> = (0..n).map(|i| format!("n{i}")).collect();
    let mut edges = (0..n - 1).map(|i| (i, i + 1)).collect::<Vec<_>>();
    if ring {
        edges.push((0, n - 1));
    }
    Graph { nodes, edges }
}

#[test]
fn laplacian_spectra_of_path_and_ring_have_their_closed_forms() {
    // Ring C_n (2-regular): λ_k = 1 − cos(2πk/n). Path P_n, normalised: λ_k = 1 − cos(πk/(n−1)).
    for n in [5, 8, 14] {
        let ring = chain(n, true).spectral().eigenvalues;
        let mut want: Vec<f64> = (0..n)
            .map(|k| 1.0 - (std::f64::consts::TAU * k as f64 / n as f64).cos())
            .collect();
        want.sort_by(f64::total_cmp);
        for (a, b) in ring.iter().zip(&want) {
            assert!((a - b).abs() < 1e-12, "ring {n}: {ring:?} vs {want:?}");
        }
        let path = chain(n, false).spectral().eigenvalues;
        let want: Vec<f64> = (0..n)
            .map(|k| 1.0 - (std::f64::consts::PI * k as f64 / (n - 1) as f64).cos())
            .collect();
        for (a, b) in path.iter().zip(&want) {
            assert!((a - b).abs() < 1e-12, "path {n}: {path:?} vs {want:?}");
        }
    }
}

#[test]
fn wavelet_basis_and_its_inverse_multiply_to_identity() {
    let s = Graph::default_asset().spectral();
    for scale in [0.5, 1.0, 2.0] {
        let p = s.wavelet(scale) * s.wavelet_inverse(scale);
        let err = (p - nalgebra::DMatrix::identity(14, 14)).amax();
        assert!(err < 1e-10, "scale {scale}: {err}");
    }
    // Heat kernels are symmetric, and at scale 0 the identity.
    let w = s.wavelet(1.0);
    assert!((&w - w.transpose()).amax() < 1e-14);
    assert!((s.wavelet(0.0) - nalgebra::DMatrix::identity(14, 14)).amax() < 1e-12);
    // Normalised Laplacian eigenvalues lie in [0, 2], the smallest 0 (connected graph).
    assert!(
        s.eigenvalues[0].abs() < 1e-12
            && s.eigenvalues[1] > 1e-6
            && s.eigenvalues[13] <= 2.0 + 1e-12
    );
    // Chebyshev: T_2 = 2 L̃² − I.
    let t = s.chebyshev(3);
    let lt = &t[1];
    assert!((&t[2] - (lt * lt * 2.0 - nalgebra::DMatrix::identity(14, 14))).amax() < 1e-12);
}

/// ψ_s and the scaled Laplacian pinned by hand on the triangle K3, whose normalised
/// Laplacian L = I − A/2 = (3/2)(I − J/3) (J all ones) has eigenvalues 0, 3/2, 3/2: so
/// ψ_s = e^(−sL) = J/3 + e^(−3s/2)(I − J/3), and with λ_max = 3/2 the scaled Laplacian
/// L̃ = 2L/λ_max − I has 1/3 on the diagonal and −2/3 off it (T₂ = 2L̃² − I). A sign
/// flip in the exponent, or scaling by 2 instead of λ_max, gives other numbers.
#[test]
fn wavelet_and_chebyshev_bases_match_hand_computed_values() {
    let k3 = Graph {
        nodes: vec!["a".into(), "b".into(), "c".into()],
        edges: vec![(0, 1), (1, 2), (0, 2)],
    };
    let s = k3.spectral();
    for scale in [0.3, 1.0, 2.5] {
        let e = (-1.5_f64 * scale).exp();
        let (diag, off) = (1.0 / 3.0 + 2.0 / 3.0 * e, 1.0 / 3.0 - e / 3.0);
        let w = s.wavelet(scale);
        let inv = s.wavelet_inverse(scale);
        let (diag_inv, off_inv) = (1.0 / 3.0 + 2.0 / 3.0 / e, 1.0 / 3.0 - 1.0 / e / 3.0);
        for i in 0..3 {
            for j in 0..3 {
                let (want, want_inv) = if i == j {
                    (diag, diag_inv)
                } else {
                    (off, off_inv)
                };
                assert!(
                    (w[(i, j)] - want).abs() < 1e-12,
                    "ψ_{scale}[{i},{j}] = {}",
                    w[(i, j)]
                );
                assert!((inv[(i, j)] - want_inv).abs() < 1e-12, "ψ⁻¹[{i},{j}]");
            }
        }
    }
    let t = s.chebyshev(3);
    let t2_diag = 2.0 * (1.0 / 9.0 + 2.0 * 4.0 / 9.0) - 1.0; // row · column of L̃, minus 1
    let t2_off = 2.0 * (2.0 * (1.0 / 3.0) * (-2.0 / 3.0) + 4.0 / 9.0);
    for i in 0..3 {
        for j in 0..3 {
            let same = i == j;
            let want = [
                if same { 1.0 } else { 0.0 },
                if same { 1.0 / 3.0 } else { -2.0 / 3.0 },
                if same { t2_diag } else { t2_off },
            ];
            for (k, w) in want.iter().enumerate() {
                assert!(
                    (t[k][(i, j)] - w).abs() < 1e-12,
                    "T_{k}[{i},{j}] = {}",
                    t[k][(i, j)]
                );
            }
        }
    }
}

/// `model::graph_mixing`: the wavelet convolution at θ = 1 (or any equal θ) is a multiple
/// of the identity and mixes nothing; θ apart mix; the Chebyshev convolution at θ = 1 is
/// T₀ + T₁ + T₂ of the scaled Laplacian, summed here independently; baselines have none.
#[test]
fn graph_mixing_measures_the_graph_convolution() {
    use iastgcn::model::{graph_mixing, Parameters, Variant};
    let mut config = iastgcn::train::RunConfig::demo().model;
    let g = Graph::default_for(config.look_ahead);
    config.variant = Variant::Iastgcn;
    let mut p = Parameters::init(&config, 1);
    let at_start = graph_mixing(&config, &g, &p);
    assert_eq!(at_start.len(), config.blocks);
    assert!(at_start.iter().all(|&v| v < 1e-12), "{at_start:?}");
    for t in p.get_mut("blocks.0.gwc.theta").iter_mut() {
        *t = 2.5;
    }
    assert!(
        graph_mixing(&config, &g, &p)[0] < 1e-12,
        "equal θ: a multiple of I"
    );
    for (k, t) in p.get_mut("blocks.1.gwc.theta").iter_mut().enumerate() {
        *t = 1.0 + 0.1 * k as f32;
    }
    let apart = graph_mixing(&config, &g, &p);
    assert!(apart[0] < 1e-12 && apart[1] > 0.05, "{apart:?}");

    config.variant = Variant::Chebyshev;
    let p = Parameters::init(&config, 1);
    let cheb = graph_mixing(&config, &g, &p);
    let t = g.spectral().chebyshev(config.chebyshev_order);
    let psi = t
        .iter()
        .fold(nalgebra::DMatrix::zeros(g.len(), g.len()), |a, m| a + m);
    let diag = psi.diagonal().norm();
    let off = (psi.norm_squared() - diag * diag).sqrt();
    for v in &cheb {
        assert!(
            (v - off / diag).abs() < 1e-6,
            "{cheb:?} against {}",
            off / diag
        );
    }
    assert!(cheb[0] > 0.5, "{cheb:?}");

    config.variant = Variant::Mlp;
    assert!(graph_mixing(&config, &g, &Parameters::init(&config, 1)).is_empty());
}
