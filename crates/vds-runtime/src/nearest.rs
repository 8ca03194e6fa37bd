//! The original vertex nearest a point, found by a best-first search down the vertex tree
//! (for measurements that snap to the full-resolution surface, whatever level of detail is on
//! screen).
//!
//! Every node bounds its leaves by its error radius around its proxy, so
//! `|p − proxy| − error_radius` is a lower bound on the distance from `p` to any original
//! vertex below it; nodes are expanded in order of that bound until no bound beats the best
//! leaf found. Pages are decoded through the [`PageSource`] into a cache of this search alone:
//! the search makes nothing resident in the runtime's store and works while the store is in
//! use (on another thread, in asynchronous mode).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rustc_hash::FxHashMap;
use vds_format::{Page, VdtError};

use crate::store::{Node, PageSource};

/// The most pages one search decodes: a search that needs more (a point far from a model of
/// many near-equidistant pages) stops with the best vertex found so far.
pub const MAX_SEARCH_PAGES: usize = 256;

/// An original vertex and how far it is from the point asked about.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearestLeaf {
    /// The leaf's node id.
    pub node: u32,
    /// Its position (the original vertex).
    pub position: [f32; 3],
    /// Its distance from the point.
    pub distance: f32,
    /// True when the search ran to the end (the vertex is the nearest), false when it
    /// stopped at [`MAX_SEARCH_PAGES`].
    pub exact: bool,
}

/// A total order on non-negative bounds (NaN-free by construction: bounds are clamped).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Bound(f32);

impl Eq for Bound {}

impl PartialOrd for Bound {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Bound {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The original vertex of `source`'s tree nearest `point`, or `None` for a tree without
/// nodes or a point that is not finite.
///
/// # Errors
/// A page that cannot be read or decoded.
pub fn nearest_leaf(
    source: &dyn PageSource,
    point: [f32; 3],
) -> Result<Option<NearestLeaf>, VdtError> {
    if point.iter().any(|v| !v.is_finite()) {
        return Ok(None);
    }
    let mut search = Search {
        source,
        first_nodes: source
            .directory()
            .iter()
            .map(|e| e.first_node.get())
            .collect(),
        node_count: u32::try_from(source.header().node_count.get()).unwrap_or(u32::MAX),
        pages: FxHashMap::default(),
    };
    // Decoded error radii may round below the true largest distance by a grid step or so.
    let slack = 2.0 * source.header().grid_step.get();
    let distance = |node: &Node| {
        let d: f32 = (0..3)
            .map(|k| (node.proxy[k] - point[k]).powi(2))
            .sum::<f32>()
            .sqrt();
        if d.is_finite() { d } else { f32::MAX }
    };
    let mut best: Option<NearestLeaf> = None;
    let mut queue = BinaryHeap::new();
    queue.push(Reverse((Bound(0.0), 0u32)));
    let mut exact = true;
    while let Some(Reverse((Bound(bound), id))) = queue.pop() {
        if best.is_some_and(|b| bound >= b.distance) {
            break;
        }
        let Some(node) = search.node(id)? else {
            continue;
        };
        if node.is_leaf() {
            let d = distance(&node);
            if best.is_none_or(|b| d < b.distance) {
                best = Some(NearestLeaf {
                    node: id,
                    position: node.proxy,
                    distance: d,
                    exact: true,
                });
            }
            continue;
        }
        if search.pages.len() >= MAX_SEARCH_PAGES {
            exact = false;
            break;
        }
        for child in node.children() {
            let Some(child_node) = search.node(child)? else {
                continue;
            };
            let bound = if child_node.is_leaf() {
                distance(&child_node)
            } else {
                (distance(&child_node) - child_node.error_radius.max(0.0) - slack).max(0.0)
            };
            queue.push(Reverse((Bound(bound), child)));
        }
    }
    Ok(best.map(|b| NearestLeaf { exact, ..b }))
}

/// The pages one search has decoded.
struct Search<'a> {
    source: &'a dyn PageSource,
    first_nodes: Vec<u32>,
    node_count: u32,
    pages: FxHashMap<u32, Page>,
}

impl Search<'_> {
    /// Node `id`, decoding its page if this search has not yet; `None` for an id past the
    /// tree (a hostile child range).
    fn node(&mut self, id: u32) -> Result<Option<Node>, VdtError> {
        if id >= self.node_count || self.first_nodes.is_empty() {
            return Ok(None);
        }
        let index = (self.first_nodes.partition_point(|&f| f <= id).max(1) - 1) as u32;
        if !self.pages.contains_key(&index) {
            let mut page = crate::store::empty_page();
            self.source.read_page_into(index, &mut page)?;
            self.pages.insert(index, page);
        }
        Ok(self.pages[&index].node(id).map(Node::from_record))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of points as a mesh of triangles (two per cell), built into a `.vdt`.
    fn grid_file(n: u32) -> (vds_format::VdtFile<Vec<u8>>, Vec<[f32; 3]>) {
        let mut positions = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let z = ((x * 7 + y * 3) % 5) as f32 * 0.1;
                positions.push([x as f32, y as f32, z]);
            }
        }
        let mut triangles = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let a = y * n + x;
                triangles.push([a, a + 1, a + n]);
                triangles.push([a + 1, a + n + 1, a + n]);
            }
        }
        let mut scene = vds_import::Scene {
            triangle_parts: vec![0; triangles.len()],
            positions: positions.clone(),
            triangles,
            part_names: vec!["grid".into()],
            parts: Vec::new(),
            stats: Default::default(),
            warnings: Vec::new(),
        };
        // Small pages, so that the search crosses many of them.
        let options = vds_format::WriteOptions {
            page_bytes: 4096,
            ..Default::default()
        };
        let bytes = vds_build::encode_scene(&mut scene, "test", &options).unwrap();
        (vds_format::VdtFile::from_bytes(bytes).unwrap(), positions)
    }

    #[test]
    fn finds_the_same_vertex_as_a_linear_scan() {
        let (file, positions) = grid_file(40);
        let mut random = crate::unit_random(7);
        for _ in 0..200 {
            let p = [
                random() * 50.0 - 5.0,
                random() * 50.0 - 5.0,
                random() * 4.0 - 2.0,
            ];
            let found = nearest_leaf(&file, p).unwrap().unwrap();
            let brute = positions
                .iter()
                .map(|q| (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f32>().sqrt())
                .fold(f32::MAX, f32::min);
            assert!(found.exact);
            // Positions pass through the file's quantisation: compare distances, to a step.
            assert!(
                (found.distance - brute).abs() <= 1e-3,
                "{p:?}: {} vs {brute}",
                found.distance
            );
        }
    }

    #[test]
    fn a_point_that_is_not_finite_finds_nothing() {
        let (file, _) = grid_file(4);
        assert_eq!(nearest_leaf(&file, [f32::NAN, 0.0, 0.0]).unwrap(), None);
    }
}
