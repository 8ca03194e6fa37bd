//! The vertex tree's invariants, checked against the scene it was built from. Tests run this
//! on every tree they build; `vds-info --verify` will run it on trees read back from disk.
//!
//! Each check follows the definition, not the builder's shortcut: "deepest node supporting
//! two corners" is checked as "supports two, and no child does", not by the leaf-walk the
//! builder uses.

use vds_import::Scene;

use crate::bounds::{NormalCone, triangle_normal};
use crate::quadric::{cross, dot, sub};
use crate::tree::{Node, VertexTree};

/// A broken invariant.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TreeError {
    /// Structural problem: ranges, parents, children, degree, leaves.
    #[error("node {node}: {message}")]
    Structure {
        /// The node.
        node: u32,
        /// What is wrong.
        message: String,
    },
    /// A triangle is not a subtri of exactly one node, or of the wrong one.
    #[error("triangle {triangle}: {message}")]
    Subtri {
        /// The triangle.
        triangle: u32,
        /// What is wrong.
        message: String,
    },
    /// A bound (error radius, sphere, cone) does not contain what it must.
    #[error("node {node}: {message}")]
    Bound {
        /// The node.
        node: u32,
        /// What is wrong.
        message: String,
    },
}

/// Relative slack for distance comparisons: stored values are rounded up to `f32`, but the
/// checks recompute distances in `f64` from `f32` inputs, so equality cases may differ in the
/// last bits.
const DISTANCE_SLACK: f64 = 1e-6;
/// Angular slack for cone containment (radians).
const ANGLE_SLACK: f64 = 1e-5;

/// Checks every invariant of `tree` against `scene`. Leaves hold no bounds (they never
/// unfold): their proxy is checked to be their vertex, spheres and cones are checked on inner
/// nodes.
pub fn verify_tree(tree: &VertexTree, scene: &Scene) -> Result<(), TreeError> {
    verify_structure(tree, scene)?;
    verify_subtris(tree, scene)?;
    verify_bounds(tree, scene)
}

fn structure(node: usize, message: impl Into<String>) -> TreeError {
    TreeError::Structure {
        node: node as u32,
        message: message.into(),
    }
}

fn verify_structure(tree: &VertexTree, scene: &Scene) -> Result<(), TreeError> {
    let v = scene.positions.len();
    if v == 0 {
        return if tree.nodes.is_empty() {
            Ok(())
        } else {
            Err(structure(0, "empty scene, non-empty tree"))
        };
    }
    if tree.leaf_vertex.len() != v
        || tree.vertex_rank.len() != v
        || tree.leaf_node.len() != v
        || tree.leaf_positions.len() != v
    {
        return Err(structure(0, "leaf arrays do not match the vertex count"));
    }
    let root = tree.nodes.first().ok_or_else(|| structure(0, "no root"))?;
    if root.parent != Node::NO_PARENT || root.leaf_begin != 0 || root.leaf_end as usize != v {
        return Err(structure(
            0,
            "root must cover every leaf and have no parent",
        ));
    }
    // Every original vertex is exactly one leaf.
    let mut seen = vec![false; v];
    for (rank, &vertex) in tree.leaf_vertex.iter().enumerate() {
        let slot = seen
            .get_mut(vertex as usize)
            .ok_or_else(|| structure(0, "leaf vertex out of range"))?;
        if std::mem::replace(slot, true) {
            return Err(structure(
                0,
                format!("vertex {vertex} is more than one leaf"),
            ));
        }
        if tree.vertex_rank[vertex as usize] as usize != rank {
            return Err(structure(
                0,
                format!("vertex_rank of vertex {vertex} is wrong"),
            ));
        }
        let leaf = tree.leaf_node[rank] as usize;
        let node = tree
            .nodes
            .get(leaf)
            .ok_or_else(|| structure(leaf, "leaf node out of range"))?;
        if !node.is_leaf() || node.leaf_begin as usize != rank || node.leaf_end as usize != rank + 1
        {
            return Err(structure(leaf, format!("is not the leaf of rank {rank}")));
        }
        if tree.leaf_positions[rank] != scene.positions[vertex as usize] {
            return Err(structure(leaf, "leaf proxy differs from its vertex"));
        }
    }
    let mut leaves = 0usize;
    for (id, node) in tree.nodes.iter().enumerate() {
        if node.leaf_begin >= node.leaf_end {
            return Err(structure(id, "empty leaf range"));
        }
        if node.is_leaf() {
            leaves += 1;
            if node.leaf_count() != 1 {
                return Err(structure(id, "leaf covers more than one vertex"));
            }
            continue;
        }
        // Inner nodes' bounds are numbered in id order.
        if node.bounds as usize != id - leaves {
            return Err(structure(id, "bounds index out of order"));
        }
        if node.child_count < 2 || node.child_count > 8 {
            return Err(structure(
                id,
                format!("degree {} outside 2..=8", node.child_count),
            ));
        }
        let children = node.children();
        if children.start as usize <= id || children.end as usize > tree.nodes.len() {
            return Err(structure(
                id,
                "children out of range or before their parent",
            ));
        }
        // Children partition the parent's leaf range in order.
        let mut next = node.leaf_begin;
        for c in children {
            let child = &tree.nodes[c as usize];
            if child.parent as usize != id
                || child.depth != node.depth + 1
                || child.leaf_begin != next
            {
                return Err(structure(
                    c as usize,
                    "child does not continue its parent's range",
                ));
            }
            next = child.leaf_end;
        }
        if next != node.leaf_end {
            return Err(structure(id, "children do not cover the parent's range"));
        }
    }
    if leaves != v {
        return Err(structure(0, format!("{leaves} leaves for {v} vertices")));
    }
    if tree.bounds.len() != tree.nodes.len() - leaves {
        return Err(structure(0, "bounds do not match the inner nodes"));
    }
    Ok(())
}

fn verify_subtris(tree: &VertexTree, scene: &Scene) -> Result<(), TreeError> {
    let mut owner = vec![u32::MAX; scene.triangles.len()];
    if tree.subtris.len() != scene.triangles.len() {
        return Err(TreeError::Subtri {
            triangle: 0,
            message: format!(
                "{} subtris for {} triangles",
                tree.subtris.len(),
                scene.triangles.len()
            ),
        });
    }
    for (id, node) in tree.nodes.iter().enumerate() {
        let range = node.subtri_begin as usize..node.subtri_end as usize;
        let list = tree
            .subtris
            .get(range)
            .ok_or_else(|| structure(id, "subtri range out of bounds"))?;
        for &t in list {
            let slot = owner
                .get_mut(t as usize)
                .ok_or_else(|| structure(id, "subtri id out of range"))?;
            if *slot != u32::MAX {
                return Err(TreeError::Subtri {
                    triangle: t,
                    message: format!("is a subtri of nodes {} and {id}", *slot),
                });
            }
            *slot = id as u32;
        }
    }
    for (t, &node) in owner.iter().enumerate() {
        let subtri = |message: String| TreeError::Subtri {
            triangle: t as u32,
            message,
        };
        if node == u32::MAX {
            return Err(subtri("is a subtri of no node".into()));
        }
        let ranks = scene.triangles[t].map(|v| tree.vertex_rank[v as usize]);
        let supported = |n: &Node| ranks.iter().filter(|&&r| n.supports_rank(r)).count();
        let n = &tree.nodes[node as usize];
        if supported(n) < 2 {
            return Err(subtri(format!(
                "node {node} supports fewer than two corners"
            )));
        }
        for c in n.children() {
            if supported(&tree.nodes[c as usize]) > 1 {
                return Err(subtri(format!(
                    "child {c} of node {node} supports two corners"
                )));
            }
        }
    }
    Ok(())
}

fn verify_bounds(tree: &VertexTree, scene: &Scene) -> Result<(), TreeError> {
    let position = |v: u32| scene.positions[v as usize].map(f64::from);
    let distance =
        |a: [f64; 3], b: [f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
    let within = |d: f64, r: f32| d <= f64::from(r) * (1.0 + DISTANCE_SLACK) + 1e-30;
    // Triangles with a corner under each node, gathered per leaf and checked up the ancestry.
    let mut incident: Vec<Vec<u32>> = vec![Vec::new(); scene.positions.len()];
    for (t, tri) in scene.triangles.iter().enumerate() {
        for &v in tri {
            incident[v as usize].push(t as u32);
        }
    }
    for (id, node) in tree.nodes.iter().enumerate() {
        let bound = |message: String| TreeError::Bound {
            node: id as u32,
            message,
        };
        // A leaf's proxy is its vertex (checked with the structure) and it has no bounds.
        let Some(bounds) = tree.bounds_of(id as u32) else {
            continue;
        };
        let proxy = bounds.proxy.map(f64::from);
        let center = bounds.sphere_center.map(f64::from);
        let cone = NormalCone {
            axis: bounds.cone_axis.map(f64::from),
            half_angle: f64::from(bounds.cone_half_angle),
        };
        // Σ area·distance² from the proxy to the incident planes, and Σ area, for the
        // surface error.
        // `reach` is the farthest a plane's anchor corner lies from the proxy: the scale of
        // the rounding in each plane distance.
        let (mut squared, mut area, mut reach) = (0.0f64, 0.0f64, 0.0f64);
        for rank in node.leaf_begin..node.leaf_end {
            let vertex = tree.leaf_vertex[rank as usize];
            let d = distance(proxy, position(vertex));
            if !within(d, bounds.error_radius) {
                return Err(bound(format!(
                    "vertex {vertex} is {d} from the proxy, error radius {}",
                    bounds.error_radius
                )));
            }
            for &t in &incident[vertex as usize] {
                let [a, b, c] = scene.triangles[t as usize].map(position);
                for corner in [a, b, c] {
                    let d = distance(center, corner);
                    if !within(d, bounds.sphere_radius) {
                        return Err(bound(format!(
                            "triangle {t} leaves the bounding sphere by {d}"
                        )));
                    }
                }
                let inside = |normal| {
                    if bounds.cone_two_sided {
                        cone.contains_either_way(normal, ANGLE_SLACK)
                    } else {
                        cone.contains(normal, ANGLE_SLACK)
                    }
                };
                if let Some(normal) = triangle_normal(a, b, c) {
                    if !inside(normal) {
                        return Err(bound(format!("normal of triangle {t} is outside the cone")));
                    }
                    let twice_area = cross(sub(b, a), sub(c, a));
                    let weight = dot(twice_area, twice_area).sqrt() / 2.0;
                    let offset = sub(proxy, a);
                    let d = dot(normal, offset);
                    reach = reach.max(dot(offset, offset).sqrt());
                    squared += weight * d * d;
                    area += weight;
                }
            }
        }
        let surface = if area > 0.0 {
            (squared / area).sqrt()
        } else {
            0.0
        };
        let stored = f64::from(bounds.surface_error);
        // The builder sums the same planes in another order and form: the quadric's
        // expansion `pᵀAp + 2bᵀp + c` cancels terms of the order of `w·|p|²`, which can
        // leave an absolute error of about 10⁻⁷·|p| in the root. This check's own distances
        // round at about 10⁻¹⁶ of the corner's distance from the proxy (`reach`): a node whose
        // leaves all coincide stores 0 where this sum finds ~10⁻¹⁵. The slack allows both.
        let magnitude = proxy.iter().fold(0.0f64, |m, c| m.max(c.abs()));
        let slack = 1e-6 * (surface + f64::from(bounds.error_radius) + magnitude + reach);
        if !(stored + slack >= surface && bounds.surface_error <= bounds.error_radius) {
            return Err(bound(format!(
                "surface error {stored} is not the planes' RMS distance {surface} (error radius {})",
                bounds.error_radius
            )));
        }
    }
    Ok(())
}
