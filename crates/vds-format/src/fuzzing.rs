//! Entry points for the fuzz targets (feature `fuzzing`; not a stable API).
//!
//! The `.vdt` reader fuzz target reaches the page decoder only through zstd frames and
//! checksums, which random mutations rarely keep valid. This entry point hands the decoder
//! raw page streams directly.

use crate::codec::{PageShape, STREAMS, Scratch, decode_page};
use crate::grid::Grid;
use crate::read::{Limits, check_records};
use crate::{Page, VdtError, VdtFile};

/// The input [`decode_page_and_check`] takes for page `index` of `file`: the page's shape
/// and the file's limits, then its decompressed streams (fuzzing seeds, and tests that
/// mutate real pages).
pub fn page_input<B: AsRef<[u8]>>(file: &VdtFile<B>, index: u32) -> Result<Vec<u8>, VdtError> {
    let entry = file
        .directory()
        .get(index as usize)
        .ok_or_else(|| VdtError::invalid("page index", format!("{index} is out of range")))?;
    let raw = zstd::bulk::decompress(file.frame(entry), entry.raw_length.get() as usize).map_err(
        |e| VdtError::Decompress {
            page: index,
            message: e.to_string(),
        },
    )?;
    let header = file.header();
    let mut input = Vec::with_capacity(28 + raw.len());
    for word in [
        entry.first_node.get(),
        entry.node_count.get(),
        entry.first_triangle.get(),
        entry.triangle_count.get(),
        header.node_count.get() as u32,
        header.vertex_count.get() as u32,
        file.metadata().part_names.len() as u32,
    ] {
        input.extend_from_slice(&word.to_le_bytes());
    }
    input.extend_from_slice(&raw);
    Ok(input)
}

/// Decodes `data` as one page and checks what the decoder accepts. The first 28 bytes are
/// seven little-endian `u32`s: the page's first node, node count, first triangle and
/// triangle count, and the file's node, vertex and part counts; the rest is the page's
/// stream table and streams, as a page's zstd frame holds them. Returns whether the page
/// decoded.
///
/// # Panics
/// When the decoder returns records that the reader's record checks
/// ([`crate::VdtFile::validate_page`]) refuse: the decoder promises to make those checks.
pub fn decode_page_and_check(data: &[u8]) -> bool {
    let Some((head, raw)) = data.split_first_chunk::<28>() else {
        return false;
    };
    let word = |k: usize| {
        u32::from_le_bytes([
            head[4 * k],
            head[4 * k + 1],
            head[4 * k + 2],
            head[4 * k + 3],
        ])
    };
    let (first_node, node_count, first_triangle, triangle_count) =
        (word(0), word(1), word(2), word(3));
    // The reader's directory check bounds the records a page may decode to by its length
    // (see `read.rs`); the same bound keeps this harness from allocating by a count.
    let least = 4 * STREAMS as u64 + u64::from(node_count) * 5 + u64::from(triangle_count) * 4;
    if node_count == 0 || least > raw.len() as u64 {
        return false;
    }
    // What the reader's directory check guarantees of every page (see `read.rs`): its nodes
    // and triangles have 32-bit ids, and the file holds its nodes.
    let node_end = u64::from(first_node) + u64::from(node_count);
    if node_end > u64::from(u32::MAX)
        || u64::from(first_triangle) + u64::from(triangle_count) > u64::from(u32::MAX)
    {
        return false;
    }
    let file_nodes = u64::from(word(4)).clamp(node_end, u64::from(u32::MAX));
    let limits = Limits {
        nodes: file_nodes,
        vertices: u64::from(word(5)),
        max_depth: 64,
        parts: u64::from(word(6)),
    };
    let shape = PageShape {
        first_node,
        node_count,
        first_triangle,
        triangle_count,
        file_nodes,
        file_vertices: limits.vertices,
        max_depth: limits.max_depth as u32,
        parts: limits.parts,
    };
    let grid = Grid {
        origin: [0.0; 3],
        step: 1.0,
    };
    let mut page = Page {
        first_node,
        first_triangle,
        nodes: Vec::new(),
        triangles: Vec::new(),
    };
    let decoded = decode_page(
        &grid,
        raw,
        &shape,
        &mut Scratch::default(),
        &mut page.nodes,
        &mut page.triangles,
    );
    if decoded.is_ok()
        && let Err(e) = check_records("fuzzed page", &page, &limits)
    {
        panic!("the decoder accepted records the reader refuses: {e}");
    }
    decoded.is_ok()
}
