//! The figures a file's header and metadata state about its tree, counted again from the
//! decoded pages. Opening a file checks what the directory alone can tell (the node and
//! triangle totals, the page count); a header depth or a degree histogram can only be told
//! false by decoding every page, which is what `vds-info --verify` does. Without this check a
//! file whose header says depth 41,075 for a tree 8 deep, with valid checksums, would verify,
//! and `vds-info` would print the false figure.
//!
//! This module counts and compares; it does not decode (see `read.rs`) or check the tree's
//! shape (the builder's `verify_tree` does).

use crate::{Page, VdtError, VdtFile};

/// A figure of the header or metadata that [`TreeFigures`] can recount from the pages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StatedField {
    /// Header `node_count`: the nodes in the pages.
    NodeCount,
    /// Header `triangle_count`: the triangles in the pages.
    TriangleCount,
    /// Header `vertex_count`: the leaves (nodes without children).
    VertexCount,
    /// Header `page_count`: the pages.
    PageCount,
    /// Header `max_depth`: the depth of the deepest node.
    MaxDepth,
    /// Metadata `degree_histogram[k]`: the nodes with `k` children.
    DegreeHistogram(u8),
    /// Metadata `input_vertices`: vertices as read, before welding; at least the leaves
    /// (welding and dropping unreferenced vertices only remove vertices).
    InputVertices,
    /// Metadata `input_triangles`: triangles as read, before dropping degenerate ones; at
    /// least the triangles in the tree.
    InputTriangles,
    /// Metadata `parts[i].triangles`: the triangles whose part is `i`.
    PartTriangles(u32),
}

impl StatedField {
    /// True when the stated value must equal the counted one; false when it must be at least
    /// the counted one (the metadata's input counts, which the build only reduces).
    pub fn must_equal(self) -> bool {
        !matches!(
            self,
            StatedField::InputVertices | StatedField::InputTriangles
        )
    }

    /// What an error message adds after the two values: nothing for a figure that must be
    /// equal, that it is a lower bound otherwise.
    pub(crate) fn bound_note(self) -> &'static str {
        if self.must_equal() {
            ""
        } else {
            " (it must state at least that)"
        }
    }
}

impl std::fmt::Display for StatedField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StatedField::NodeCount => f.write_str("header node_count"),
            StatedField::TriangleCount => f.write_str("header triangle_count"),
            StatedField::VertexCount => f.write_str("header vertex_count"),
            StatedField::PageCount => f.write_str("header page_count"),
            StatedField::MaxDepth => f.write_str("header max_depth"),
            StatedField::DegreeHistogram(k) => write!(f, "metadata degree_histogram[{k}]"),
            StatedField::InputVertices => f.write_str("metadata input_vertices"),
            StatedField::InputTriangles => f.write_str("metadata input_triangles"),
            StatedField::PartTriangles(i) => write!(f, "metadata parts[{i}].triangles"),
        }
    }
}

/// What a file's decoded pages hold, counted: the figures to hold its header and metadata
/// to ([`VdtFile::check_figures`]). Add every page once, in any order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TreeFigures {
    /// Pages added.
    pub pages: u64,
    /// Nodes in them.
    pub nodes: u64,
    /// Triangles in them.
    pub triangles: u64,
    /// Nodes without children.
    pub leaves: u64,
    /// The deepest node's depth.
    pub max_depth: u64,
    /// Nodes with `k` children, `k = 0..=8` (the decoder refuses more).
    pub degree_histogram: [u64; 9],
    /// Triangles per part id, up to the largest id seen (ids of [`crate::MAX_PARTS`] and
    /// above, which no file may hold, are counted in `triangles` only).
    pub part_triangles: Vec<u64>,
}

impl TreeFigures {
    /// Counts one decoded page.
    pub fn add_page(&mut self, page: &Page) {
        self.pages += 1;
        self.nodes += page.nodes.len() as u64;
        self.triangles += page.triangles.len() as u64;
        for n in &page.nodes {
            // Pages from the reader hold at most 8 children per node; a page from elsewhere
            // with more counts them as 8, which no true histogram matches either.
            self.degree_histogram[usize::from(n.child_count).min(8)] += 1;
            self.max_depth = self.max_depth.max(u64::from(n.depth.get()));
        }
        self.leaves = self.degree_histogram[0];
        for t in &page.triangles {
            let part = t.part.get() as usize;
            if part as u64 >= crate::MAX_PARTS {
                continue;
            }
            if part >= self.part_triangles.len() {
                self.part_triangles.resize(part + 1, 0);
            }
            self.part_triangles[part] += 1;
        }
    }

    /// The figures of a file's pages, all of them decoded (in parallel).
    pub fn of_file<B: AsRef<[u8]> + Sync>(file: &VdtFile<B>) -> Result<TreeFigures, VdtError> {
        let mut figures = TreeFigures::default();
        for page in file.read_all_pages()? {
            figures.add_page(&page);
        }
        Ok(figures)
    }
}

impl<B: AsRef<[u8]>> VdtFile<B> {
    /// Holds every figure the header and metadata state about the tree to `figures`, counted
    /// from all of this file's pages: the counts, the depth, the degree histogram and the
    /// per-part triangle counts must be equal, the input vertex and triangle counts at least the leaves and triangles. The
    /// first false one is a [`VdtError::Misstated`] naming it.
    pub fn check_figures(&self, figures: &TreeFigures) -> Result<(), VdtError> {
        use StatedField::*;
        let (h, m) = (self.header(), self.metadata());
        let mut stated = vec![
            (PageCount, u64::from(h.page_count.get()), figures.pages),
            (NodeCount, h.node_count.get(), figures.nodes),
            (TriangleCount, h.triangle_count.get(), figures.triangles),
            (VertexCount, h.vertex_count.get(), figures.leaves),
            (MaxDepth, u64::from(h.max_depth.get()), figures.max_depth),
        ];
        stated.extend((0..9).map(|k| {
            let counted = figures.degree_histogram[k];
            (DegreeHistogram(k as u8), m.degree_histogram[k], counted)
        }));
        stated.push((InputVertices, m.input_vertices, figures.leaves));
        stated.push((InputTriangles, m.input_triangles, figures.triangles));
        // A file that states no part records has no per-part counts to hold.
        stated.extend(m.parts.iter().enumerate().map(|(i, p)| {
            let counted = figures.part_triangles.get(i).copied().unwrap_or(0);
            (PartTriangles(i as u32), p.triangles, counted)
        }));
        for (field, stated, counted) in stated {
            let holds = if field.must_equal() {
                stated == counted
            } else {
                stated >= counted
            };
            if !holds {
                return Err(VdtError::Misstated {
                    field,
                    stated,
                    counted,
                });
            }
        }
        Ok(())
    }
}
