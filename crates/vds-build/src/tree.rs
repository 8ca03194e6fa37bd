//! The vertex tree: the data structure every other part of vds reads.
//!
//! Nodes are stored breadth-first (node 0 is the root, a node's children are contiguous,
//! every parent precedes its children). Leaves are numbered depth-first by *leaf rank*, so
//! each node covers a contiguous leaf range and "node N supports vertex V" is a range test on
//! V's rank: the paper's NodePath test without pointer chasing.

use crate::octree::NO_PARENT;

/// One node of the vertex tree: its place in the tree. An inner node's proxy and bounds are
/// in [`VertexTree::bounds`]; a leaf's proxy is its vertex's position and it has no bounds
/// (a leaf never unfolds, so nothing tests them, and `.vdt` files do not store them).
/// Keeping the bounds of inner nodes only makes a node 32 bytes instead of 76: leaves are
/// about 70 % of the nodes, and on the dev VMs fresh memory is much of a build's time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Node {
    /// Parent id, or [`Node::NO_PARENT`] for the root.
    pub parent: u32,
    /// First child id; children are `first_child .. first_child + child_count`.
    pub first_child: u32,
    /// Number of children: 0 for a leaf, else 2..=8.
    pub child_count: u8,
    /// Depth below the root.
    pub depth: u16,
    /// First leaf rank this node supports.
    pub leaf_begin: u32,
    /// One past the last leaf rank this node supports.
    pub leaf_end: u32,
    /// Start of this node's subtris in [`VertexTree::subtris`].
    pub subtri_begin: u32,
    /// End of this node's subtris in [`VertexTree::subtris`].
    pub subtri_end: u32,
    /// An inner node's index in [`VertexTree::bounds`] (inner nodes are numbered in id
    /// order); [`Node::NO_BOUNDS`] for a leaf.
    pub bounds: u32,
}

/// An inner node's proxy and bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeBounds {
    /// The proxy vertex.
    pub proxy: [f32; 3],
    /// Largest distance from the proxy to any supported original vertex (object units).
    pub error_radius: f32,
    /// How far the surface moves when the node folds, as the quadric measures it: the
    /// root-mean-square distance from the proxy to the planes of the triangles around each
    /// supported vertex, weighted by area (each triangle once per supported corner). At most
    /// the error radius, since each plane passes through a supported vertex; small where the
    /// vertices slide along a flat region, large where a fold flattens a ridge or a thin part.
    pub surface_error: f32,
    /// Centre of a sphere containing every triangle with a corner under this node.
    pub sphere_center: [f32; 3],
    /// Radius of that sphere.
    pub sphere_radius: f32,
    /// Unit axis of a cone containing the normals of every triangle with a corner under this
    /// node (zero-area triangles have no normal and are not bounded).
    pub cone_axis: [f32; 3],
    /// Half-angle of that cone in radians; negative when it bounds no normal.
    pub cone_half_angle: f32,
    /// The cone is two-sided: every normal `n` has `n` or `−n` inside it (see
    /// [`crate::bounds::NormalCone`]). Chosen when the one-sided cone is wider than a
    /// hemisphere, where it could tell nothing anyway, and the two-sided one is narrower.
    pub cone_two_sided: bool,
}

impl NodeBounds {
    /// Bounds not yet computed.
    pub const EMPTY: NodeBounds = NodeBounds {
        proxy: [0.0; 3],
        error_radius: 0.0,
        surface_error: 0.0,
        sphere_center: [0.0; 3],
        sphere_radius: 0.0,
        cone_axis: [0.0, 0.0, 1.0],
        cone_half_angle: -1.0,
        cone_two_sided: false,
    };
}

impl Node {
    /// The parent id of the root.
    pub const NO_PARENT: u32 = NO_PARENT;

    /// The bounds index of a leaf.
    pub const NO_BOUNDS: u32 = u32::MAX;

    /// A leaf (until it is given children) with its place in the tree set.
    pub(crate) fn topology(leaf_begin: u32, leaf_end: u32, parent: u32, depth: u16) -> Node {
        Node {
            parent,
            first_child: 0,
            child_count: 0,
            depth,
            leaf_begin,
            leaf_end,
            subtri_begin: 0,
            subtri_end: 0,
            bounds: Node::NO_BOUNDS,
        }
    }

    /// True for a leaf (an original vertex).
    pub fn is_leaf(&self) -> bool {
        self.child_count == 0
    }

    /// The ids of the children.
    pub fn children(&self) -> std::ops::Range<u32> {
        self.first_child..self.first_child + u32::from(self.child_count)
    }

    /// True when this node supports the vertex with leaf rank `rank`.
    pub fn supports_rank(&self, rank: u32) -> bool {
        self.leaf_begin <= rank && rank < self.leaf_end
    }

    /// Number of original vertices under this node.
    pub fn leaf_count(&self) -> u32 {
        self.leaf_end - self.leaf_begin
    }
}

/// A vertex tree over a scene's vertices and triangles.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VertexTree {
    /// Nodes, breadth-first; node 0 is the root. Empty for an empty scene.
    pub nodes: Vec<Node>,
    /// Proxy and bounds of each inner node, at its [`Node::bounds`] index.
    pub bounds: Vec<NodeBounds>,
    /// Position of each leaf rank: a leaf's proxy.
    pub leaf_positions: Vec<[f32; 3]>,
    /// Vertex id (index into the scene's positions) of each leaf rank.
    pub leaf_vertex: Vec<u32>,
    /// Leaf rank of each vertex id (inverse of `leaf_vertex`).
    pub vertex_rank: Vec<u32>,
    /// Node id of the leaf with each leaf rank.
    pub leaf_node: Vec<u32>,
    /// Triangle ids (indices into the scene's triangles) grouped by the node they are subtris
    /// of; each node's are at `subtri_begin..subtri_end`, in increasing triangle id.
    pub subtris: Vec<u32>,
    /// Node ids where each depth starts, plus the node count at the end. Empty for a tree
    /// read from a `.vdt` file, whose nodes are in page order rather than by depth.
    pub level_starts: Vec<u32>,
}

impl VertexTree {
    /// The root id (the tree must not be empty).
    pub const ROOT: u32 = 0;

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// The proxy and bounds of node `id`, or `None` for a leaf.
    pub fn bounds_of(&self, id: u32) -> Option<&NodeBounds> {
        let node = &self.nodes[id as usize];
        (!node.is_leaf()).then(|| &self.bounds[node.bounds as usize])
    }

    /// The proxy of node `id`: for a leaf, its vertex's position.
    pub fn proxy(&self, id: u32) -> [f32; 3] {
        match self.bounds_of(id) {
            Some(bounds) => bounds.proxy,
            None => self.leaf_positions[self.nodes[id as usize].leaf_begin as usize],
        }
    }

    /// Centre and radius of node `id`'s bounding sphere (a leaf's: its position, radius 0,
    /// as `.vdt` files store it).
    pub fn sphere(&self, id: u32) -> ([f32; 3], f32) {
        match self.bounds_of(id) {
            Some(bounds) => (bounds.sphere_center, bounds.sphere_radius),
            None => (self.proxy(id), 0.0),
        }
    }

    /// Depth of the deepest node (0 for a single node).
    pub fn max_depth(&self) -> usize {
        match self.level_starts.len() {
            0 => self
                .nodes
                .iter()
                .map(|n| usize::from(n.depth))
                .max()
                .unwrap_or(0),
            levels => levels - 2,
        }
    }

    /// The node a triangle is a subtri of: the deepest node supporting two or more of its
    /// corners (Luebke & Erikson §2.1). Walks up from the middle corner's leaf.
    pub fn subtri_node(&self, triangle: [u32; 3]) -> u32 {
        subtri_node_of_ranks(
            &self.nodes,
            &self.leaf_node,
            triangle.map(|v| self.vertex_rank[v as usize]),
        )
    }

    /// The subtris of node `id`.
    pub fn subtris_of(&self, id: u32) -> &[u32] {
        let n = &self.nodes[id as usize];
        &self.subtris[n.subtri_begin as usize..n.subtri_end as usize]
    }

    /// A histogram of child counts: entry `k` counts nodes with `k` children.
    pub fn degree_histogram(&self) -> [u64; 9] {
        let mut histogram = [0u64; 9];
        for n in &self.nodes {
            histogram[usize::from(n.child_count).min(8)] += 1;
        }
        histogram
    }
}

/// The deepest node of `nodes` supporting two or more of the leaf ranks `ranks`
/// ([`VertexTree::subtri_node`]); `leaf_node` maps a rank to its leaf. The middle rank must
/// be a leaf of `nodes`; a rank past every leaf (a corner outside a subtree) stops no walk.
pub(crate) fn subtri_node_of_ranks(nodes: &[Node], leaf_node: &[u32], mut ranks: [u32; 3]) -> u32 {
    ranks.sort_unstable();
    // The deepest pairwise common ancestor involves the middle rank: any node covering
    // ranks[0] and ranks[2] also covers ranks[1], since ranges are contiguous.
    let mut node = leaf_node[ranks[1] as usize];
    loop {
        let n = &nodes[node as usize];
        if n.leaf_begin <= ranks[0] || n.leaf_end > ranks[2] {
            return node;
        }
        node = n.parent;
    }
}
