//! The sensor graph: nodes (sensor channels) and undirected edges, loaded from a TOML
//! asset (`assets/graph.toml`) so that other sensors need no code change.

use std::path::Path;

use nalgebra::DMatrix;
use serde::Deserialize;

/// The asset shipped with the engine.
pub const DEFAULT_ASSET: &str = include_str!("../../assets/graph.toml");

#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct GraphError {
    pub file: String,
    pub message: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Asset {
    nodes: Vec<String>,
    edges: Vec<[String; 2]>,
}

/// Named nodes and undirected edges (by node index, `i < j`, no self loops).
#[derive(Clone, Debug, PartialEq)]
pub struct Graph {
    pub nodes: Vec<String>,
    pub edges: Vec<(usize, usize)>,
}

impl Graph {
    pub fn default_asset() -> Graph {
        Graph::parse(DEFAULT_ASSET, "assets/graph.toml").expect("embedded graph asset is valid")
    }

    pub fn load(path: &Path) -> Result<Graph, GraphError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| GraphError {
            file: file.clone(),
            message: e.to_string(),
        })?;
        Graph::parse(&text, &file)
    }

    /// Parses and checks a graph asset; `file` names the source in errors.
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

    pub fn len(&self) -> usize {
        self.nodes.len()
    }

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
}
