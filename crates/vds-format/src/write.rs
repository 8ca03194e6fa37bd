//! Writing `.vdt` files: page layout, parallel compression, and an atomic, deterministic
//! write (a temporary file beside the target, renamed into place).
//!
//! Page layout: the tree is cut into *treelets*. A page starts from a group of siblings and
//! takes child groups breadth-first until its byte budget is reached; the groups that did
//! not fit start later pages, taken depth-first (last in, first out), so a root-to-leaf path
//! crosses about `depth / treelet depth` pages and neighbouring treelets sit next to each other
//! in the file. A treelet that ends before its page is full (near the leaves) leaves the rest
//! of the page to the next pending treelet, which is its nearest neighbour in the tree. The first page, the top of the tree, has a quarter of the budget so opening a
//! file decodes little. Nodes are renumbered in page order: every page holds a contiguous
//! node range, siblings stay contiguous, and parents precede children.

use std::collections::VecDeque;
use std::path::Path;

use rayon::prelude::*;
use xxhash_rust::xxh3::xxh3_64;
use zerocopy::IntoBytes;
use zerocopy::little_endian::{U32, U64};

use crate::layout::*;
use crate::{Grid, Metadata, VdtError};

/// Default bytes of decoded records per page: large enough to compress well, small enough to
/// page in fast. 128 KiB, the size of Nanite's streaming pages, compresses to about 14 KiB on
/// the bunny and 5 KiB on CAD scenes; 64 KiB pages cost the bunny 3.5 % more bytes (zstd's
/// per-frame tables weigh more on small frames).
pub const DEFAULT_PAGE_BYTES: u32 = 128 * 1024;
/// Default zstd level: on generated CAD scenes level 6 gave smaller files than 9 (17.5 vs
/// 17.7 B/triangle) in half the time; 15 saves 15 % more at 10× the time.
pub const DEFAULT_ZSTD_LEVEL: i32 = 6;

/// The nodes of a tree to write, by id: a slice of records, or a builder's own node array
/// that makes each record when the writer asks for it, so that a whole tree of records (76
/// bytes a node, 0.6 GB at 10 M triangles) never has to exist beside the tree.
pub trait NodeSource: Sync {
    /// Number of nodes; ids are `0 .. node_count()`.
    fn node_count(&self) -> usize;
    /// The record of node `id` (below [`NodeSource::node_count`]).
    fn node_record(&self, id: u32) -> NodeRecord;
}

impl NodeSource for Vec<NodeRecord> {
    fn node_count(&self) -> usize {
        self.len()
    }

    fn node_record(&self, id: u32) -> NodeRecord {
        self[id as usize]
    }
}

/// A tree to write, with nodes in any order where children are contiguous and node 0 is the
/// root. Each node's subtris are `triangles[subtri_begin .. subtri_begin + subtri_count]`.
#[derive(Debug, Clone)]
pub struct TreeContent<N: NodeSource = Vec<NodeRecord>> {
    /// Nodes; ids are indices. Written in page order (renumbered) by the writer.
    pub nodes: N,
    /// Triangles grouped by node.
    pub triangles: Vec<TriangleRecord>,
    /// Number of leaves (original vertices).
    pub vertex_count: u64,
    /// Depth of the deepest node.
    pub max_depth: u32,
    /// The grid positions are stored on; every leaf position must lie on it
    /// ([`Grid::snap`] the scene before building).
    pub grid: Grid,
    /// The metadata section.
    pub metadata: Metadata,
}

/// Options for [`write_file`].
#[derive(Debug, Clone, Copy)]
pub struct WriteOptions {
    /// zstd level (1..=22).
    pub zstd_level: i32,
    /// Target raw bytes per page.
    pub page_bytes: u32,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            zstd_level: DEFAULT_ZSTD_LEVEL,
            page_bytes: DEFAULT_PAGE_BYTES,
        }
    }
}

/// What was written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WriteReport {
    /// Total file size.
    pub file_bytes: u64,
    /// Size of all pages' encoded streams before zstd.
    pub raw_page_bytes: u64,
    /// Compressed size of all pages.
    pub compressed_page_bytes: u64,
    /// Number of pages.
    pub pages: u32,
}

/// A sibling group: `count` nodes from `first`.
#[derive(Debug, Clone, Copy)]
struct Group {
    first: u32,
    count: u32,
}

/// One planned page: its sibling groups, in order, and how many subtris they own.
struct PagePlan {
    groups: Vec<Group>,
    triangles: usize,
}

/// Plans pages: the sibling groups of each page, and its triangle count (read here once,
/// where each group's size is measured anyway).
fn plan_pages(nodes: &impl NodeSource, page_bytes: u32) -> Vec<PagePlan> {
    // A group's subtris, with its nodes' child groups put in `children`: one record of each
    // node (records are made on demand, and planning runs on one thread).
    let measure = |g: &Group, children: &mut Vec<Group>| -> u64 {
        children.clear();
        let mut triangles = 0u64;
        for id in g.first..g.first + g.count {
            let n = nodes.node_record(id);
            triangles += u64::from(n.subtri_count.get());
            if n.child_count > 0 {
                children.push(Group {
                    first: n.first_child.get(),
                    count: u32::from(n.child_count),
                });
            }
        }
        triangles
    };
    let mut children = Vec::new();
    let mut pages = Vec::new();
    let mut stack = vec![Group { first: 0, count: 1 }];
    while let Some(start) = stack.pop() {
        let budget = if pages.is_empty() {
            page_bytes / 4
        } else {
            page_bytes
        };
        let mut page = Vec::new();
        let mut page_triangles = 0u64;
        let mut bytes = 0u64;
        let mut queue = VecDeque::from([start]);
        loop {
            // When this treelet is exhausted, keep filling the page with the next pending
            // treelet: the stack's top is the nearest unfinished part of the tree.
            if queue.is_empty() {
                match stack.pop() {
                    Some(next) if !pages.is_empty() => queue.push_back(next),
                    Some(next) => {
                        stack.push(next);
                        break;
                    }
                    None => break,
                }
            }
            let group = queue[0];
            let triangles = measure(&group, &mut children);
            let size =
                NODE_BYTES as u64 * u64::from(group.count) + TRIANGLE_BYTES as u64 * triangles;
            if !page.is_empty() && bytes + size > u64::from(budget) {
                break;
            }
            queue.pop_front();
            page.push(group);
            page_triangles += triangles;
            bytes += size;
            queue.extend(children.iter().copied());
        }
        stack.extend(queue.into_iter().rev());
        pages.push(PagePlan {
            groups: page,
            triangles: page_triangles as usize,
        });
    }
    pages
}

/// Lays the tree out in pages and encodes the whole file in memory.
pub fn encode<N: NodeSource>(
    content: &TreeContent<N>,
    options: &WriteOptions,
) -> Result<(Vec<u8>, WriteReport), VdtError> {
    let nodes = &content.nodes;
    let node_count = nodes.node_count();
    if node_count == 0 {
        return Err(VdtError::invalid(
            "tree",
            "a .vdt file needs at least one node",
        ));
    }
    let plan = plan_pages(nodes, options.page_bytes.max(NODE_BYTES as u32));

    // Renumber nodes and triangles in page order.
    let mut new_id = vec![NO_NODE; node_count];
    let mut order = Vec::with_capacity(node_count);
    for page in &plan {
        for group in &page.groups {
            for old in group.first..group.first + group.count {
                new_id[old as usize] = order.len() as u32;
                order.push(old);
            }
        }
    }
    if order.len() != node_count {
        return Err(VdtError::invalid(
            "tree",
            "some nodes are not reachable from the root",
        ));
    }
    let map = |id: U32| -> U32 {
        if id.get() == NO_NODE {
            id
        } else {
            U32::new(new_id[id.get() as usize])
        }
    };

    // Each page's span: first node and triangle in page order, and their counts.
    let mut spans = Vec::with_capacity(plan.len());
    let (mut node_at, mut triangle_at) = (0usize, 0usize);
    for page in &plan {
        let node_count: usize = page.groups.iter().map(|g| g.count as usize).sum();
        let triangle_count = page.triangles;
        spans.push((node_at, node_count, triangle_at, triangle_count));
        node_at += node_count;
        triangle_at += triangle_count;
    }
    // Page bodies, encoded and compressed in parallel. Each page gathers its own records in
    // page order (renumbered) from the caller's tree: no copy of the whole tree is made, which
    // at 10 M triangles was 0.7 GB beside the tree itself.
    let grid = &content.grid;
    let frames: Vec<(Vec<u8>, usize)> = spans
        .par_iter()
        .map_init(
            PageWork::new(options.zstd_level),
            |work, &(n0, nc, t0, _)| {
                let PageWork {
                    compressor,
                    scratch,
                    records,
                    triangles,
                    raw,
                } = work;
                records.clear();
                triangles.clear();
                for &old in &order[n0..n0 + nc] {
                    let mut n = nodes.node_record(old);
                    n.parent = map(n.parent);
                    n.first_child = map(n.first_child);
                    let begin = n.subtri_begin.get() as usize;
                    let count = n.subtri_count.get() as usize;
                    n.subtri_begin = U32::new((t0 + triangles.len()) as u32);
                    triangles.extend_from_slice(&content.triangles[begin..begin + count]);
                    records.push(n);
                }
                crate::codec::encode_page_into(scratch, grid, n0 as u32, records, triangles, raw)?;
                let frame = compressor
                    .compress(raw)
                    .expect("zstd compression of an in-memory buffer cannot fail");
                Ok((frame, raw.len()))
            },
        )
        .collect::<Result<_, VdtError>>()?;
    drop(new_id);
    drop(order);

    for (i, (frame, raw_length)) in frames.iter().enumerate() {
        if *raw_length as u64 > crate::read::MAX_COMPRESSION_RATIO * frame.len() as u64 {
            return Err(VdtError::invalid(
                format!("page {i}"),
                "compresses beyond the ratio readers accept as a decompression bomb",
            ));
        }
    }
    // A writer never produces a file its readers refuse.
    content.metadata.check(triangle_at as u64)?;
    let metadata = rkyv::to_bytes::<rkyv::rancor::Error>(&content.metadata)
        .map_err(|e| VdtError::invalid("metadata", e.to_string()))?;
    let metadata_offset = HEADER_BYTES as u64;
    let directory_offset = metadata_offset + metadata.len() as u64;
    let directory_length = (plan.len() * PAGE_ENTRY_BYTES) as u64;
    let mut offset = directory_offset + directory_length;
    let mut directory = Vec::with_capacity(plan.len());
    for (&(n0, nc, t0, tc), (frame, raw_length)) in spans.iter().zip(&frames) {
        directory.push(PageEntry {
            offset: U64::new(offset),
            compressed_length: U32::new(frame.len() as u32),
            raw_length: U32::new(*raw_length as u32),
            first_node: U32::new(n0 as u32),
            node_count: U32::new(nc as u32),
            first_triangle: U32::new(t0 as u32),
            triangle_count: U32::new(tc as u32),
            checksum: U64::new(xxh3_64(frame)),
        });
        offset += frame.len() as u64;
    }
    let mut header = Header {
        magic: VDT_MAGIC,
        version: U32::new(VDT_VERSION),
        header_size: U32::new(HEADER_BYTES as u32),
        file_size: U64::new(offset),
        node_count: U64::new(node_count as u64),
        triangle_count: U64::new(triangle_at as u64),
        vertex_count: U64::new(content.vertex_count),
        page_count: U32::new(plan.len() as u32),
        max_depth: U32::new(content.max_depth),
        metadata: SectionRef {
            offset: U64::new(metadata_offset),
            length: U64::new(metadata.len() as u64),
            checksum: U64::new(xxh3_64(&metadata)),
        },
        directory: SectionRef {
            offset: U64::new(directory_offset),
            length: U64::new(directory_length),
            checksum: U64::new(xxh3_64(directory.as_bytes())),
        },
        grid_origin: grid.origin.map(zerocopy::little_endian::F32::new),
        grid_step: zerocopy::little_endian::F32::new(grid.step),
        header_checksum: U64::new(0),
    };
    header.header_checksum = U64::new(xxh3_64(&header.as_bytes()[..HEADER_BYTES - 8]));

    let mut out = Vec::with_capacity(offset as usize);
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(&metadata);
    out.extend_from_slice(directory.as_bytes());
    let raw_page_bytes = frames.iter().map(|(_, r)| *r as u64).sum();
    let compressed_page_bytes = frames.iter().map(|(f, _)| f.len() as u64).sum();
    for (frame, _) in frames {
        out.extend_from_slice(&frame);
    }
    let report = WriteReport {
        file_bytes: out.len() as u64,
        raw_page_bytes,
        compressed_page_bytes,
        pages: plan.len() as u32,
    };
    Ok((out, report))
}

/// What a writing task keeps from page to page: a zstd context, the encoder's working
/// arrays, and the page's gathered records and encoding. Rayon's `map_init` makes one per
/// task it splits off (a handful per thread), where a context per page cost a table setup
/// for every 20 KiB page and streams that grew from empty each time.
struct PageWork {
    compressor: zstd::bulk::Compressor<'static>,
    scratch: crate::codec::EncodeScratch,
    records: Vec<NodeRecord>,
    triangles: Vec<TriangleRecord>,
    raw: Vec<u8>,
}

impl PageWork {
    fn new(zstd_level: i32) -> impl Fn() -> PageWork + Sync {
        move || PageWork {
            compressor: zstd::bulk::Compressor::new(zstd_level)
                .expect("a zstd context at a level zstd accepts"),
            scratch: Default::default(),
            records: Vec::new(),
            triangles: Vec::new(),
            raw: Vec::new(),
        }
    }
}

/// Encodes the tree and writes it to `path` atomically ([`crate::output::write_atomically`]):
/// the bytes go to a temporary file in the same directory, which is renamed over `path` only
/// once complete, so an interrupted or failed write never leaves a partial `.vdt`; stale
/// partials of killed writes are removed, and a `path` that names a device, a directory or
/// anything else that is not a regular file is refused before anything is encoded.
pub fn write_file<N: NodeSource>(
    path: &Path,
    content: &TreeContent<N>,
    options: &WriteOptions,
) -> Result<WriteReport, VdtError> {
    crate::output::resolve_output(path)?;
    let (bytes, report) = encode(content, options)?;
    crate::output::write_atomically(path, |out| out.write_all(&bytes))?;
    Ok(report)
}
