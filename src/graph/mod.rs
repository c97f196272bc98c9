//! The sensor graph: nodes (sensor channels) and undirected edges, loaded from a TOML
//! asset (`assets/graph.toml`) so that other sensors need no code change.

use std::path::Path;

use nalgebra::DMatrix;
use serde::Deserialize;

/// The asset shipped with the engine.
pub const DEFAULT_ASSET: &str = include_str!("../../assets/graph.toml");
/// The asset of a look-ahead model: [`DEFAULT_ASSET`] and the planned motion's nodes.
pub const LOOK_AHEAD_ASSET: &str = include_str!("../../assets/graph-look-ahead.toml");

/// The joint-input nodes of the hybrid machine's graph: the motor encoders of the three
/// limb lengths (Q1–Q3) and the two head angles (Q4, Q5). With the pose a function of
/// them, they are the commanded pose (calibration's inputs, the offline baselines' inputs).
pub const HYBRID_JOINT_INPUTS: [&str; 5] = ["Q1", "Q2", "Q3", "Q4", "Q5"];

/// A graph asset that cannot be read or breaks a rule of docs/twin.md "Sensor graph asset".
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct GraphError {
    /// The asset's file name.
    pub file: String,
    /// What is wrong, naming the node or edge.
    pub message: String,
}

impl crate::error::StageError for GraphError {}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Asset {
    nodes: Vec<String>,
    edges: Vec<[String; 2]>,
}

/// Named nodes and undirected edges (by node index, `i < j`, no self loops).
#[derive(Clone, Debug, PartialEq)]
pub struct Graph {
    /// Node names (sensor channels), in node order.
    pub nodes: Vec<String>,
    /// Edges as node-index pairs `(i, j)` with `i < j`, in file order.
    pub edges: Vec<(usize, usize)>,
}

impl Graph {
    /// The embedded assets/graph.toml: the 14 nodes of Table II.
    ///
    /// ```
    /// use iastgcn::graph::Graph;
    ///
    /// let graph = Graph::default_asset();
    /// assert_eq!(graph.len(), 14);
    /// assert_eq!(graph.nodes[0], "E1");
    /// ```
    pub fn default_asset() -> Graph {
        // invariant: the embedded asset is parsed in tests/graph.rs.
        Graph::parse(DEFAULT_ASSET, "assets/graph.toml").expect("embedded graph asset is valid")
    }

    /// Reads and checks the graph asset at `path`.
    pub fn load(path: &Path) -> Result<Graph, GraphError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| GraphError {
            file: file.clone(),
            message: e.to_string(),
        })?;
        Graph::parse(&text, &file)
    }

    /// The embedded assets/graph-look-ahead.toml: the 14 nodes of Table II and the
    /// controller's planned motion to the next tick (`planX`, `planY`, `planZ`).
    ///
    /// ```
    /// use iastgcn::graph::Graph;
    ///
    /// let graph = Graph::look_ahead_asset();
    /// assert_eq!(graph.len(), 17);
    /// assert_eq!(graph.nodes[..14], Graph::default_asset().nodes[..]);
    /// assert_eq!(graph.nodes[14], "planX");
    /// ```
    pub fn look_ahead_asset() -> Graph {
        // invariant: the embedded asset is parsed in tests/graph.rs.
        Graph::parse(LOOK_AHEAD_ASSET, "assets/graph-look-ahead.toml")
            .expect("embedded graph asset is valid")
    }

    /// The embedded graph of a model that predicts `look_ahead` ticks ahead: the planned
    /// motion's graph from 1 on, Table II's at 0.
    pub fn default_for(look_ahead: usize) -> Graph {
        if look_ahead > 0 {
            Graph::look_ahead_asset()
        } else {
            Graph::default_asset()
        }
    }

    /// The file at `path`, or the embedded [`Graph::default_for`] `look_ahead` when there
    /// is none.
    pub fn load_or_default(path: Option<&Path>, look_ahead: usize) -> Result<Graph, GraphError> {
        path.map_or_else(|| Ok(Graph::default_for(look_ahead)), Graph::load)
    }

    /// Parses and checks a graph asset; `file` names the source in errors.
    ///
    /// ```
    /// use iastgcn::graph::Graph;
    ///
    /// let graph = Graph::parse(
    ///     r#"nodes = ["a", "b", "c"]
    ///        edges = [["c", "a"]]"#,
    ///     "g.toml",
    /// )?;
    /// assert_eq!(graph.edges, vec![(0, 2)]);
    ///
    /// let looped = r#"nodes = ["a"]
    ///                 edges = [["a", "a"]]"#;
    /// let err = Graph::parse(looped, "g.toml").unwrap_err();
    /// assert_eq!(err.to_string(), r#"g.toml: self loop on node "a""#);
    /// # Ok::<(), iastgcn::graph::GraphError>(())
    /// ```
    pub fn parse(text: &str, file: &str) -> Result<Graph, GraphError> {
        let err = |message: String| GraphError {
            file: file.to_string(),
            message,
        };
        let asset: Asset = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        if asset.nodes.is_empty() {
            return Err(err("`nodes` is empty".to_string()));
        }
        for (i, n) in asset.nodes.iter().enumerate() {
            if n.is_empty() || n.contains(',') || n.trim() != n {
                return Err(err(format!(
                    "node name {n:?} must be non-empty, without commas or outer spaces"
                )));
            }
            if asset.nodes[..i].contains(n) {
                return Err(err(format!("node {n:?} is listed twice")));
            }
        }
        let index = |name: &str| {
            asset
                .nodes
                .iter()
                .position(|n| n == name)
                .ok_or_else(|| err(format!("edge names unknown node {name:?}")))
        };
        let mut edges = Vec::with_capacity(asset.edges.len());
        for [a, b] in &asset.edges {
            let (i, j) = (index(a)?, index(b)?);
            if i == j {
                return Err(err(format!("self loop on node {a:?}")));
            }
            let e = (i.min(j), i.max(j));
            if edges.contains(&e) {
                return Err(err(format!("edge {a:?}–{b:?} is listed twice")));
            }
            edges.push(e);
        }
        Ok(Graph {
            nodes: asset.nodes,
            edges,
        })
    }

    /// Number of nodes N.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True without nodes (a parsed graph always has some).
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Symmetric 0/1 adjacency matrix.
    pub fn adjacency(&self) -> DMatrix<f64> {
        let mut a = DMatrix::zeros(self.len(), self.len());
        for &(i, j) in &self.edges {
            a[(i, j)] = 1.0;
            a[(j, i)] = 1.0;
        }
        a
    }

    /// Â = D̃^(−1/2) (A + I) D̃^(−1/2), with D̃ the degrees of A + I: the propagation
    /// matrix of the Kipf–Welling graph convolution (the one T-GCN uses).
    pub fn renormalized_adjacency(&self) -> DMatrix<f64> {
        let n = self.len();
        let a = self.adjacency() + DMatrix::identity(n, n);
        let d: Vec<f64> = (0..n).map(|i| 1.0 / a.row(i).sum().sqrt()).collect();
        DMatrix::from_fn(n, n, |i, j| d[i] * a[(i, j)] * d[j])
    }
}

/// The spectral quantities of docs/model.md ("Graph"), computed once on the CPU in f64.
#[derive(Clone, Debug)]
pub struct Spectral {
    /// Normalised Laplacian L = I − D^(−1/2) A D^(−1/2).
    pub laplacian: DMatrix<f64>,
    /// Eigenvalues λ of L, ascending.
    pub eigenvalues: Vec<f64>,
    /// Orthonormal eigenvectors U of L, as columns in the order of the eigenvalues.
    pub eigenvectors: DMatrix<f64>,
}

impl Graph {
    /// L = I − D^(−1/2) A D^(−1/2); an isolated node (degree 0) keeps a zero row and column.
    pub fn normalized_laplacian(&self) -> DMatrix<f64> {
        let a = self.adjacency();
        let n = self.len();
        let d: Vec<f64> = (0..n).map(|i| a.row(i).sum()).collect();
        DMatrix::from_fn(n, n, |i, j| {
            let off = if d[i] > 0.0 && d[j] > 0.0 {
                a[(i, j)] / (d[i] * d[j]).sqrt()
            } else {
                0.0
            };
            let diag = if i == j && d[i] > 0.0 { 1.0 } else { 0.0 };
            diag - off
        })
    }

    /// Exact symmetric eigendecomposition of the normalised Laplacian (N is small).
    pub fn spectral(&self) -> Spectral {
        let laplacian = self.normalized_laplacian();
        let eig = laplacian.clone().symmetric_eigen();
        let mut order: Vec<usize> = (0..self.len()).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let eigenvalues = order.iter().map(|&i| eig.eigenvalues[i]).collect();
        let eigenvectors = DMatrix::from_fn(self.len(), self.len(), |r, c| {
            eig.eigenvectors[(r, order[c])]
        });
        Spectral {
            laplacian,
            eigenvalues,
            eigenvectors,
        }
    }
}

impl Spectral {
    /// U diag(f(λ)) Uᵀ.
    fn filter(&self, f: impl Fn(f64) -> f64) -> DMatrix<f64> {
        let u = &self.eigenvectors;
        let d = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
            self.eigenvalues.len(),
            self.eigenvalues.iter().map(|&l| f(l)),
        ));
        u * d * u.transpose()
    }

    /// Heat-kernel wavelet basis ψ_s = U diag(exp(−s λ)) Uᵀ (GWNN).
    pub fn wavelet(&self, s: f64) -> DMatrix<f64> {
        self.filter(|l| (-s * l).exp())
    }

    /// Its inverse ψ_s⁻¹ = U diag(exp(s λ)) Uᵀ.
    pub fn wavelet_inverse(&self, s: f64) -> DMatrix<f64> {
        self.filter(|l| (s * l).exp())
    }

    /// Chebyshev polynomials T_0..T_{order−1} of the scaled Laplacian
    /// L̃ = 2L/λ_max − I (for the `iastgcn-s` ablation and the `eat-gcn` baseline).
    pub fn chebyshev(&self, order: usize) -> Vec<DMatrix<f64>> {
        let n = self.laplacian.nrows();
        let lmax = self.eigenvalues.last().copied().unwrap_or(0.0).max(1e-12);
        let scaled = &self.laplacian * (2.0 / lmax) - DMatrix::identity(n, n);
        let mut out: Vec<DMatrix<f64>> = Vec::with_capacity(order);
        for k in 0..order {
            let t = match k {
                0 => DMatrix::identity(n, n),
                1 => scaled.clone(),
                _ => &scaled * &out[k - 1] * 2.0 - &out[k - 2],
            };
            out.push(t);
        }
        out
    }
}
