//! The sharded build: the same vertex tree as [`crate::build_tree`], made by independent jobs.
//!
//! The tight octree's top levels depend only on the bounds and counts of the vertices in
//! each cell, so a small *top tree* can be planned first ([`plan()`]). Its leaves, the *shard
//! roots*, are octree nodes whose subtrees depend only on their own vertices in input order:
//! each shard builds the subtrees of a contiguous run of roots ([`build_shard`]) with the
//! in-memory builder's own clustering and attribute passes, and encodes the file's pages of
//! each region below the top that it can finish alone (the file's pages fall in regions that
//! each lie under one root). A merge ([`merge_to`]) fills the top nodes from the roots'
//! accumulated sums, places the triangles whose corners lie in different shards, numbers the
//! regions and writes the file one part at a time, copying the shards' pages. The result is the tree the
//! in-memory build makes, node for node and bit for bit, in the same file, byte for byte.
//!
//! What crosses shard borders:
//! - A triangle with a corner in a shard is read by that shard: its leaf attributes (quadric,
//!   cone, sphere) sum all of a vertex's triangles, in triangle order, with the corners that
//!   lie elsewhere as plain positions.
//! - A triangle whose two corners lie under one root belongs to a node of that root's subtree
//!   (the deepest node supporting two corners); one whose corners lie under three roots
//!   belongs to a top node. When the third corner of the first kind lies under another root of
//!   the same shard, the shard places the triangle itself. Otherwise some corners' leaf ranks
//!   are only known to other shards (or the owner is a top node), so every shard reports the
//!   ranks of its corners of such triangles ([`CrossCorner`]) and the merge joins them; the
//!   shard leaves the pages of their owners as records for the merge to encode.
//! - Welding is exact: coincident vertices fall in one cell, so no weld crosses a border.
//!
//! Modules: [`mod@plan`] (the top tree and the shards), `part` (one shard's build),
//! `numbering` (a shard's own numbers for its vertices), `container` (the layout of the
//! build's files), `input_file` (a shard's input, `.vdtin`), `seal` (a root's subtree as the
//! merge takes it: top records, regions as the file's pages), `part_file` (a shard's output,
//! `.vdtpart`), `merge` (the top nodes, renumbering, the file).

mod container;
mod input_file;
mod merge;
mod numbering;
mod part;
mod part_file;
pub mod plan;
mod seal;
mod source;

pub use container::Durability;
pub use input_file::{
    INPUT_MAGIC, INPUT_WRITER_BYTES, MAX_FILES_PER_PASS, read_shard_input, shard_triangle_counts,
    stamp_shard_inputs, write_shard_inputs,
};
pub use merge::{PartHead, PartRead, merge, merge_to};
pub use part::{
    CrossCorner, InputTriangle, InputVertex, OpenPage, RegionPage, RegionPart, RootPart,
    ShardInput, ShardPart, build_shard, build_shard_from, build_shard_into, input_triangle,
    input_vertex, roots_of_vertices, shard_input_of,
};
pub use part_file::{
    PART_MAGIC, part_from_bytes, part_head_from_bytes, part_header, read_part, read_part_checked,
    read_part_head, write_part, write_shard,
};
pub use plan::{Plan, PlanMetadata, plan};
pub use source::{PlanScene, TriangleRun};

use std::path::PathBuf;

/// Why a plan, shard or merge failed.
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    /// The scene has no vertices.
    #[error("nothing to build: the input has no triangles")]
    Empty,
    /// The input a shard read is not the one the plan was made from.
    #[error("the input differs from the plan's: {0}")]
    InputChanged(String),
    /// The plan file is not a plan, or was edited.
    #[error("{path}: not a valid plan: {reason}")]
    BadPlan {
        /// The plan file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A shard's input or part file is damaged, truncated or not for this plan and shard.
    #[error("{path}: {reason}")]
    BadFile {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A shard index the plan does not have.
    #[error("shard {index}: the plan has {shards} shards, numbered from 0")]
    NoSuchShard {
        /// The index asked for.
        index: u32,
        /// The plan's shard count.
        shards: u32,
    },
    /// The set of parts given to a merge is not the plan's shards, once each.
    #[error("{0}")]
    PartSet(String),
    /// The merged tree cannot be encoded as a file.
    #[error("cannot encode the merged file: {0}")]
    Encode(#[from] vds_format::VdtError),
    /// Writing the merged file failed.
    #[error("cannot write the merged file: {0}")]
    Write(std::io::Error),
    /// Writing an output failed (it is left as it was).
    #[error(transparent)]
    Output(#[from] vds_format::OutputError),
    /// Reading or spilling the input failed.
    #[error(transparent)]
    Import(#[from] vds_import::ImportError),
    /// Reading a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// A bumpy `n` × `n` grid of triangles in one part, for the sharded build's unit tests.
#[cfg(test)]
fn bumpy_grid(n: u32) -> vds_import::Scene {
    let mut scene = vds_import::Scene::default();
    for y in 0..n {
        for x in 0..n {
            let z = ((x * 7 + y * 3) % 5) as f32 * 0.1;
            scene.positions.push([x as f32, y as f32, z]);
        }
    }
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let v = y * n + x;
            scene.triangles.push([v, v + 1, v + n]);
            scene.triangles.push([v + 1, v + n + 1, v + n]);
        }
    }
    scene.triangle_parts = vec![0; scene.triangles.len()];
    scene.part_names = vec!["grid".into()];
    scene
}
