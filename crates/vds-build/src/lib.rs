//! The vds vertex-tree builder: Luebke & Erikson's view-dependent simplification hierarchy
//! ("View-Dependent Simplification of Arbitrary Polygonal Environments", SIGGRAPH 1997).
//!
//! One global tree spans the whole scene: leaves are the original vertices, each inner node
//! clusters its children into one proxy vertex. [`build_tree`] clusters vertices with a
//! tight octree ([`octree`]), places proxies by quadric error metrics ([`quadric`]), bounds
//! each node's error, triangles and normals ([`bounds`]), and assigns every triangle to the
//! one node whose folding removes it (its *subtri* node). [`verify_tree`] checks all of
//! that against the scene.

#![deny(missing_docs)]

pub mod bounds;
mod build;
pub mod contraction;
mod isa;
pub mod octree;
mod prefault;
pub mod quadric;
pub mod shard;
mod tree;
mod vdt;
mod verify;

pub use build::{BuildTimings, Builder, build_tree, build_tree_by, build_tree_timed};
pub use tree::{Node, NodeBounds, VertexTree};
pub use vdt::{
    TreeNodes, VerifyError, encode_scene, encode_scene_by, part_records, snap_positions,
    snap_to_grid, tree_content, tree_from_file, verify_file,
};
pub use verify::{TreeError, verify_tree};
