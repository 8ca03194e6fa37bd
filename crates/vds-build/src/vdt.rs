//! Between the in-memory [`VertexTree`] and the `.vdt` file: turning a built tree into the
//! format's records, and a file's pages back into a tree and the scene it encodes (leaf
//! positions and triangles by leaf rank), which is what `vds-info --verify` checks.

use rayon::prelude::*;
use vds_format::{
    Grid, NO_NODE, NodeRecord, NodeSource, TreeContent, TriangleRecord, VdtError, VdtFile,
};
use vds_import::Scene;
use zerocopy::little_endian::{F32, U16, U32};

use crate::prefault::collect_populated;
use crate::tree::{Node, NodeBounds, VertexTree};

/// Node `id` of `tree` as the format's record. A leaf's record holds its position and no
/// bounds (radius 0, an empty cone), as the file stores it.
fn record(tree: &VertexTree, id: u32) -> NodeRecord {
    let node = &tree.nodes[id as usize];
    let leaf_position = if node.is_leaf() {
        tree.leaf_positions[node.leaf_begin as usize]
    } else {
        [0.0; 3]
    };
    node_record(node, tree.bounds_of(id), leaf_position)
}

/// The format's record of `node`, with its bounds (an inner node) or its position (a leaf).
pub(crate) fn node_record(
    node: &Node,
    bounds: Option<&NodeBounds>,
    leaf_position: [f32; 3],
) -> NodeRecord {
    let f = |x: f32| F32::new(x);
    let (proxy, error_radius, surface_error, sphere, cone, two_sided) = match bounds {
        Some(b) => (
            b.proxy,
            b.error_radius,
            b.surface_error,
            [
                b.sphere_center[0],
                b.sphere_center[1],
                b.sphere_center[2],
                b.sphere_radius,
            ],
            [
                b.cone_axis[0],
                b.cone_axis[1],
                b.cone_axis[2],
                b.cone_half_angle,
            ],
            b.cone_two_sided,
        ),
        None => {
            let p = leaf_position;
            (
                p,
                0.0,
                0.0,
                [p[0], p[1], p[2], 0.0],
                [0.0, 0.0, 1.0, -1.0],
                false,
            )
        }
    };
    NodeRecord {
        parent: U32::new(node.parent),
        first_child: U32::new(if node.is_leaf() {
            NO_NODE
        } else {
            node.first_child
        }),
        child_count: node.child_count,
        flags: if two_sided {
            vds_format::FLAG_TWO_SIDED_CONE
        } else {
            0
        },
        depth: U16::new(node.depth),
        leaf_begin: U32::new(node.leaf_begin),
        leaf_end: U32::new(node.leaf_end),
        subtri_begin: U32::new(node.subtri_begin),
        subtri_count: U32::new(node.subtri_end - node.subtri_begin),
        proxy: proxy.map(f),
        error_radius: f(error_radius),
        surface_error: f(surface_error),
        sphere: sphere.map(f),
        cone: cone.map(f),
    }
}

/// The metadata's part records for `scene`: each part's parent and colour as imported and
/// its triangle count, counted from the scene's triangles (every one becomes one subtri of
/// the file). Empty when the scene names no parts, or a triangle's part has no name (the
/// file then states nothing beyond the names).
pub fn part_records(scene: &Scene) -> Vec<vds_format::PartInfo> {
    let mut counts = PartCounts::new(scene.part_names.len());
    for &part in &scene.triangle_parts {
        counts.add(part, 1);
    }
    counts.records(|i| {
        let info = scene.parts.get(i).copied().unwrap_or_default();
        (info.parent, info.color)
    })
}

/// Triangles counted by part, for [`part_records`] and the sharded merge: a part out of range makes the records
/// empty (the file then states nothing of its parts beyond their names).
pub(crate) struct PartCounts {
    counts: Option<Vec<u64>>,
}

impl PartCounts {
    pub(crate) fn new(parts: usize) -> PartCounts {
        PartCounts {
            counts: Some(vec![0; parts]),
        }
    }

    /// Counts `n` triangles of `part`.
    pub(crate) fn add(&mut self, part: u32, n: u64) {
        if let Some(counts) = &mut self.counts {
            match counts.get_mut(part as usize) {
                Some(count) => *count += n,
                None => self.counts = None,
            }
        }
    }

    /// The part records, from each part's parent and colour as imported.
    pub(crate) fn records(
        &self,
        info: impl Fn(usize) -> (Option<u32>, Option<[f32; 4]>),
    ) -> Vec<vds_format::PartInfo> {
        let Some(counts) = &self.counts else {
            return Vec::new();
        };
        (0..counts.len())
            .map(|i| {
                let (parent, color) = info(i);
                vds_format::PartInfo {
                    parent: parent
                        .filter(|&p| (p as usize) < i)
                        .unwrap_or(vds_format::NO_PART),
                    color,
                    triangles: counts[i],
                }
            })
            .collect()
    }
}

/// Moves every vertex of `scene` to the nearest point of the `.vdt` grid for its bounds and
/// returns that grid. Build the tree after snapping, so every bound the builder computes is
/// exact for the positions the file will hold.
pub fn snap_to_grid(scene: &mut Scene) -> Grid {
    snap_positions(&mut scene.positions)
}

/// [`snap_to_grid`] for positions alone (a scene whose triangles are elsewhere).
pub fn snap_positions(positions: &mut [[f32; 3]]) -> Grid {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in positions.iter() {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    if positions.is_empty() {
        (min, max) = ([0.0; 3], [1.0; 3]);
    }
    let grid = Grid::for_bounds(min, max);
    positions.par_iter_mut().for_each(|p| *p = grid.snap(*p));
    grid
}

/// Subtris per parallel run of nodes sorting their subtris in [`tree_content`].
const TRIANGLES_PER_SORT_RUN: usize = 1 << 16;

/// A built tree's nodes as the writer reads them: each record is made when asked for, so
/// the writer never needs a second copy of the whole tree in the format's records.
#[derive(Debug, Clone, Copy)]
pub struct TreeNodes<'a>(pub &'a VertexTree);

impl NodeSource for TreeNodes<'_> {
    fn node_count(&self) -> usize {
        self.0.nodes.len()
    }

    fn node_record(&self, id: u32) -> NodeRecord {
        record(self.0, id)
    }
}

/// The format's view of a built tree: its nodes (records made on demand, see [`TreeNodes`]),
/// and triangles grouped by node with corners as leaf ranks. `metadata` is stored as given;
/// `grid` is the one the scene was snapped to ([`snap_to_grid`]) before the tree was built.
/// The scene is not needed once this returns.
pub fn tree_content<'a>(
    tree: &'a VertexTree,
    scene: &Scene,
    metadata: vds_format::Metadata,
    grid: Grid,
) -> TreeContent<TreeNodes<'a>> {
    let mut triangles = collect_populated(tree.subtris.par_iter().map(|&t| {
        let corners =
            leading_smallest(scene.triangles[t as usize].map(|v| tree.vertex_rank[v as usize]));
        TriangleRecord {
            corners: corners.map(U32::new),
            part: U32::new(scene.triangle_parts[t as usize]),
        }
    }));
    // Within a node, subtris in order of their corners (then parts, so coincident triangles
    // of different parts have one order too): the node-relative corners then repeat in
    // patterns zstd finds, 8 % fewer corner bytes on the bunny (docs/format.md). Nodes' subtri
    // ranges follow each other in node order, so runs of nodes sort their own slices in
    // parallel.
    let mut runs: Vec<(&[Node], &mut [TriangleRecord])> = Vec::new();
    let mut rest: &mut [TriangleRecord] = &mut triangles;
    let mut run_start = 0;
    for (id, n) in tree.nodes.iter().enumerate() {
        let run_end = id + 1;
        let run_nodes = &tree.nodes[run_start..run_end];
        let run_triangles = (n.subtri_end - run_nodes[0].subtri_begin) as usize;
        if run_triangles >= TRIANGLES_PER_SORT_RUN || run_end == tree.nodes.len() {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(run_triangles);
            runs.push((run_nodes, head));
            rest = tail;
            run_start = run_end;
        }
    }
    runs.into_par_iter().for_each(|(nodes, slice)| {
        let base = nodes[0].subtri_begin as usize;
        for n in nodes {
            slice[n.subtri_begin as usize - base..n.subtri_end as usize - base]
                .sort_unstable_by_key(|t| (t.corners.map(|c| c.get()), t.part.get()));
        }
    });
    TreeContent {
        nodes: TreeNodes(tree),
        triangles,
        vertex_count: tree.leaf_vertex.len() as u64,
        max_depth: tree.max_depth() as u32,
        grid,
        metadata,
    }
}

/// The same triangle, rotated (winding kept) so that its smallest corner comes first.
pub(crate) fn leading_smallest(mut c: [u32; 3]) -> [u32; 3] {
    let first = (0..3).min_by_key(|&k| c[k]).expect("three corners");
    c.rotate_left(first);
    c
}

/// Decodes every page of a file into a tree and the scene it encodes. In that scene, vertex
/// ids are leaf ranks (positions come from the leaves' proxies) and triangle ids follow the
/// file's node order, so [`crate::verify_tree`] can check the file's tree against it.
pub fn tree_from_file<B: AsRef<[u8]> + Sync>(
    file: &VdtFile<B>,
) -> Result<(VertexTree, Scene), VdtError> {
    tree_from_pages(file, file.read_all_pages()?)
}

/// [`tree_from_file`] of pages already decoded (all of `file`'s, in order).
fn tree_from_pages<B: AsRef<[u8]>>(
    file: &VdtFile<B>,
    pages: Vec<vds_format::Page>,
) -> Result<(VertexTree, Scene), VdtError> {
    let header = file.header();
    let vertex_count = header.vertex_count.get() as usize;
    let mut nodes = Vec::with_capacity(header.node_count.get() as usize);
    let mut bounds = Vec::new();
    let mut positions = vec![[f32::NAN; 3]; vertex_count];
    let mut triangles = Vec::with_capacity(header.triangle_count.get() as usize);
    let mut triangle_parts = Vec::with_capacity(header.triangle_count.get() as usize);
    for page in pages {
        for n in &page.nodes {
            let cone = n.cone.map(|c| c.get());
            let sphere = n.sphere.map(|c| c.get());
            let proxy = n.proxy.map(|c| c.get());
            let leaf = n.child_count == 0;
            if leaf {
                // Checked below: every leaf rank has exactly one leaf.
                if let Some(p) = positions.get_mut(n.leaf_begin.get() as usize) {
                    *p = proxy;
                }
            } else {
                bounds.push(NodeBounds {
                    proxy,
                    error_radius: n.error_radius.get(),
                    surface_error: n.surface_error.get(),
                    sphere_center: [sphere[0], sphere[1], sphere[2]],
                    sphere_radius: sphere[3],
                    cone_axis: [cone[0], cone[1], cone[2]],
                    cone_half_angle: cone[3],
                    cone_two_sided: n.flags & vds_format::FLAG_TWO_SIDED_CONE != 0,
                });
            }
            nodes.push(Node {
                parent: n.parent.get(),
                first_child: if leaf { 0 } else { n.first_child.get() },
                child_count: n.child_count,
                depth: n.depth.get(),
                leaf_begin: n.leaf_begin.get(),
                leaf_end: n.leaf_end.get(),
                subtri_begin: n.subtri_begin.get(),
                subtri_end: n.subtri_begin.get() + n.subtri_count.get(),
                bounds: if leaf {
                    Node::NO_BOUNDS
                } else {
                    bounds.len() as u32 - 1
                },
            });
        }
        for t in &page.triangles {
            triangles.push(t.corners.map(|c| c.get()));
            triangle_parts.push(t.part.get());
        }
    }
    let mut leaf_node = vec![u32::MAX; vertex_count];
    for (id, n) in nodes.iter().enumerate() {
        if n.is_leaf() {
            if n.leaf_count() != 1 || leaf_node[n.leaf_begin as usize] != u32::MAX {
                return Err(VdtError::Invalid {
                    what: format!("node {id}"),
                    message: "leaf does not own exactly one new leaf rank".into(),
                });
            }
            leaf_node[n.leaf_begin as usize] = id as u32;
        }
    }
    if leaf_node.contains(&u32::MAX) {
        return Err(VdtError::Invalid {
            what: "tree".into(),
            message: "some leaf rank has no leaf node".into(),
        });
    }
    let identity: Vec<u32> = (0..vertex_count as u32).collect();
    let tree = VertexTree {
        subtris: (0..triangles.len() as u32).collect(),
        nodes,
        bounds,
        leaf_positions: positions.clone(),
        leaf_vertex: identity.clone(),
        vertex_rank: identity,
        leaf_node,
        level_starts: Vec::new(),
    };
    let scene = Scene {
        positions,
        triangles,
        triangle_parts,
        part_names: file.metadata().part_names.clone(),
        parts: (0..file.metadata().parts.len())
            .map(|i| vds_import::PartInfo {
                parent: file.metadata().part_parent(i),
                color: file.metadata().part_color(i),
            })
            .collect(),
        stats: Default::default(),
        warnings: Vec::new(),
    };
    Ok((tree, scene))
}

/// Why a file fails [`verify_file`].
#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    /// The file does not read: a checksum, a record, or a figure its header or metadata
    /// states that the pages contradict ([`VdtError::Misstated`]).
    #[error(transparent)]
    File(#[from] VdtError),
    /// The file reads, but its tree breaks an invariant of the builder.
    #[error("tree invariant broken: {0}")]
    Tree(#[from] crate::TreeError),
}

/// Everything `--verify` checks of a file: decodes every page (checksums and records), holds
/// the header's and metadata's figures to what the pages hold (counts, depth, degree
/// histogram, input counts: [`VdtFile::check_figures`]), rebuilds the tree and checks every
/// invariant of the builder ([`crate::verify_tree`]).
pub fn verify_file<B: AsRef<[u8]> + Sync>(file: &VdtFile<B>) -> Result<(), VerifyError> {
    let pages = file.read_all_pages()?;
    let mut figures = vds_format::TreeFigures::default();
    for page in &pages {
        figures.add_page(page);
    }
    // Before the tree is rebuilt: a false vertex count would otherwise surface as a leaf
    // rank without a leaf, not as the header field it is.
    file.check_figures(&figures)?;
    let (tree, scene) = tree_from_pages(file, pages)?;
    crate::verify_tree(&tree, &scene)?;
    Ok(())
}

/// The `.vdt` bytes of `scene`, built in memory: snaps the scene to the file's grid, builds the
/// tree and encodes it (what `vds-view model.obj` and the tests use instead of a file).
pub fn encode_scene(
    scene: &mut Scene,
    tool: &str,
    options: &vds_format::WriteOptions,
) -> Result<Vec<u8>, VdtError> {
    encode_scene_by(scene, tool, options, crate::Builder::default())
}

/// [`encode_scene`] with the tree made by `builder`.
pub fn encode_scene_by(
    scene: &mut Scene,
    tool: &str,
    options: &vds_format::WriteOptions,
    builder: crate::Builder,
) -> Result<Vec<u8>, VdtError> {
    let grid = snap_to_grid(scene);
    let (tree, _) = crate::build_tree_by(scene, builder);
    let metadata = vds_format::Metadata {
        tool: tool.to_string(),
        part_names: scene.part_names.clone(),
        parts: part_records(scene),
        input_vertices: scene.stats.input_vertices,
        input_triangles: scene.stats.input_triangles,
        degree_histogram: tree.degree_histogram(),
        ..Default::default()
    };
    Ok(vds_format::encode(&tree_content(&tree, scene, metadata, grid), options)?.0)
}
