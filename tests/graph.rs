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
