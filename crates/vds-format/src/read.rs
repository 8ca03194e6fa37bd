//! Reading `.vdt` files. Every file is hostile until checked: opening validates the header,
//! the metadata and the directory (sizes, offsets, counts, checksums) before anything else is
//! used, and each page is checksummed, decompressed into a buffer of the size the directory
//! promised (never more) and its records validated before they are returned. Nothing here
//! panics on bad input or allocates from a count that was not checked against the file.

use std::path::Path;

use xxhash_rust::xxh3::xxh3_64;
use zerocopy::FromBytes;

use crate::layout::*;
use crate::{Metadata, VdtError};

/// A page may decode to at most this many bytes: well above what the writer produces, and a
/// bound on what a hostile directory can make the reader allocate per page.
pub const MAX_PAGE_RAW_BYTES: u32 = 256 << 20;

/// A page may decode to at most this many times its compressed size. Records carry distinct
/// ids, ranges and coordinates, so real pages compress 1.5–10×; the bound caps what a
/// decompression bomb can make a reader allocate at 1024 × the file's size. The writer
/// refuses to produce a page beyond it.
pub const MAX_COMPRESSION_RATIO: u64 = 1024;

/// An open `.vdt` file over any bytes: a memory map in use, a `Vec` in tests.
pub struct VdtFile<B> {
    bytes: B,
    header: Header,
    directory: Vec<PageEntry>,
    metadata: Metadata,
}

/// One decoded page: a contiguous range of nodes and their subtris.
#[derive(Debug, Clone, PartialEq)]
pub struct Page {
    /// Id of the first node.
    pub first_node: u32,
    /// Index of the first triangle.
    pub first_triangle: u32,
    /// The nodes, ids `first_node ..`.
    pub nodes: Vec<NodeRecord>,
    /// The triangles, indices `first_triangle ..`.
    pub triangles: Vec<TriangleRecord>,
}

impl Page {
    /// The node with global id `id`, if it is in this page.
    pub fn node(&self, id: u32) -> Option<&NodeRecord> {
        self.nodes.get(id.checked_sub(self.first_node)? as usize)
    }

    /// The subtris of a node of this page.
    pub fn subtris(&self, node: &NodeRecord) -> &[TriangleRecord] {
        let begin = (node.subtri_begin.get() - self.first_triangle) as usize;
        &self.triangles[begin..begin + node.subtri_count.get() as usize]
    }
}

impl VdtFile<memmap2::Mmap> {
    /// Opens and memory-maps a file. Only the header, metadata and directory are read.
    ///
    /// Only a regular file (itself or through links) is opened: a FIFO would block the open
    /// or the read forever. It is opened with `O_NONBLOCK` (no effect on a regular file) and
    /// checked with `fstat` on the descriptor, so nothing swapped in after a check can block.
    pub fn open(path: &Path) -> Result<Self, VdtError> {
        let io = |cause| VdtError::Io {
            path: path.to_path_buf(),
            cause,
        };
        let mut options = std::fs::OpenOptions::new();
        options.read(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            options.custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32);
        }
        let file = options.open(path).map_err(io)?;
        if !file.metadata().map_err(io)?.is_file() {
            return Err(VdtError::NotAFile {
                path: path.to_path_buf(),
            });
        }
        VdtFile::from_bytes(map(&file).map_err(io)?)
    }
}

#[allow(unsafe_code)]
fn map(file: &std::fs::File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: a mapped file can change underneath us if another process writes it. The
    // reader copies what it keeps (header, directory, metadata) after validating it, reads
    // pages through checksums and bounds-checked slices, and never creates references that
    // assume the bytes stay fixed beyond one checked read; a concurrent writer can therefore
    // only produce a checksum or validation error (or SIGBUS on truncation), not undefined
    // behaviour in this code. `vds-build` never rewrites a file in place: it renames a new
    // file over the old one, which leaves existing maps of the old file intact.
    unsafe { memmap2::Mmap::map(file) }
}

/// What decoding a page needs besides the page itself, kept per thread and reused: a zstd
/// context (creating one per page cost more than decoding a small page), the decompressed
/// bytes and the codec's scratch arrays. Decoding page after page allocates nothing once
/// these have grown.
#[derive(Default)]
struct PageDecoder {
    zstd: Option<zstd::bulk::Decompressor<'static>>,
    raw: Vec<u8>,
    scratch: crate::codec::Scratch,
}

thread_local! {
    static DECODER: std::cell::RefCell<PageDecoder> = std::cell::RefCell::new(PageDecoder::default());
}

impl PageDecoder {
    /// Decompresses a zstd frame into `self.raw`, at most `capacity` bytes.
    fn decompress(&mut self, frame: &[u8], capacity: usize) -> std::io::Result<()> {
        let zstd = match &mut self.zstd {
            Some(z) => z,
            slot => slot.insert(zstd::bulk::Decompressor::new()?),
        };
        self.raw.clear();
        self.raw.reserve(capacity);
        zstd.decompress_to_buffer(frame, &mut self.raw)?;
        Ok(())
    }
}

fn check_range(
    what: &str,
    offset: u64,
    length: u64,
    file_size: u64,
) -> Result<(usize, usize), VdtError> {
    let end = offset
        .checked_add(length)
        .ok_or_else(|| VdtError::invalid(what, "offset + length overflows"))?;
    if end > file_size {
        return Err(VdtError::Truncated {
            what: what.to_string(),
            needed: end,
            available: file_size,
        });
    }
    Ok((offset as usize, end as usize))
}

fn check_sum(what: &str, bytes: &[u8], expected: u64) -> Result<(), VdtError> {
    let got = xxh3_64(bytes);
    if got != expected {
        return Err(VdtError::Checksum {
            what: what.to_string(),
            expected,
            got,
        });
    }
    Ok(())
}

impl<B: AsRef<[u8]>> VdtFile<B> {
    /// Validates and opens a file held in `bytes`.
    pub fn from_bytes(bytes: B) -> Result<Self, VdtError> {
        let data = bytes.as_ref();
        let file_size = data.len() as u64;
        if data.len() < 8 || data[..8] != VDT_MAGIC {
            return Err(VdtError::Magic);
        }
        let (header, _) = Header::read_from_prefix(data).map_err(|_| VdtError::Truncated {
            what: "header".into(),
            needed: HEADER_BYTES as u64,
            available: file_size,
        })?;
        if !(OLDEST_READABLE_VERSION..=VDT_VERSION).contains(&header.version.get()) {
            return Err(VdtError::Version {
                expected: VDT_VERSION,
                oldest: OLDEST_READABLE_VERSION,
                got: header.version.get(),
            });
        }
        check_sum(
            "header",
            &data[..HEADER_BYTES - 8],
            header.header_checksum.get(),
        )?;
        if header.header_size.get() as usize != HEADER_BYTES || header.file_size.get() != file_size
        {
            return Err(VdtError::invalid(
                "header",
                format!(
                    "declares file size {}, file has {file_size}",
                    header.file_size.get()
                ),
            ));
        }

        let section = header.metadata;
        let (start, end) = check_range(
            "metadata",
            section.offset.get(),
            section.length.get(),
            file_size,
        )?;
        check_sum("metadata", &data[start..end], section.checksum.get())?;
        let mut aligned = rkyv::util::AlignedVec::<16>::with_capacity(end - start);
        aligned.extend_from_slice(&data[start..end]);
        let metadata = rkyv::from_bytes::<Metadata, rkyv::rancor::Error>(&aligned)
            .map_err(|e| VdtError::invalid("metadata", format!("does not decode: {e}")))?;
        metadata.check(header.triangle_count.get())?;

        let section = header.directory;
        let (start, end) = check_range(
            "directory",
            section.offset.get(),
            section.length.get(),
            file_size,
        )?;
        let page_count = header.page_count.get() as u64;
        if page_count == 0 || (end - start) as u64 != page_count * PAGE_ENTRY_BYTES as u64 {
            return Err(VdtError::invalid(
                "directory",
                format!("{} bytes cannot hold {page_count} pages", end - start),
            ));
        }
        check_sum("directory", &data[start..end], section.checksum.get())?;
        let directory = <[PageEntry]>::ref_from_bytes(&data[start..end])
            .map_err(|_| VdtError::invalid("directory", "misaligned entries"))?
            .to_vec();
        let file = VdtFile {
            bytes,
            header,
            directory,
            metadata,
        };
        file.check_directory()?;
        Ok(file)
    }

    fn check_directory(&self) -> Result<(), VdtError> {
        let h = &self.header;
        if h.node_count.get() == 0
            || h.node_count.get() > u64::from(u32::MAX)
            || h.triangle_count.get() > u64::from(u32::MAX)
        {
            return Err(VdtError::invalid(
                "header",
                "node or triangle count out of range",
            ));
        }
        let (mut nodes, mut triangles) = (0u64, 0u64);
        for (i, page) in self.directory.iter().enumerate() {
            let what = format!("page {i}");
            check_range(
                &what,
                page.offset.get(),
                u64::from(page.compressed_length.get()),
                h.file_size.get(),
            )?;
            // The encoding spends at least 5 bytes per node (child count, parent, three
            // coordinates) and 4 per triangle (three corners, part; see codec.rs), which
            // bounds the records a page can decode to by its raw length.
            let least = 4 * crate::codec::STREAMS as u64
                + u64::from(page.node_count.get()) * 5
                + u64::from(page.triangle_count.get()) * 4;
            let raw = u64::from(page.raw_length.get());
            if page.node_count.get() == 0
                || raw < least
                || page.raw_length.get() > MAX_PAGE_RAW_BYTES
                || raw > MAX_COMPRESSION_RATIO * u64::from(page.compressed_length.get())
                || u64::from(page.first_node.get()) != nodes
                || u64::from(page.first_triangle.get()) != triangles
            {
                return Err(VdtError::invalid(&what, "directory entry is inconsistent"));
            }
            nodes += u64::from(page.node_count.get());
            triangles += u64::from(page.triangle_count.get());
        }
        if nodes != h.node_count.get() || triangles != h.triangle_count.get() {
            return Err(VdtError::invalid(
                "directory",
                "pages do not cover every node and triangle",
            ));
        }
        // Every vertex is a leaf node, and every level holds at least one node.
        if h.vertex_count.get() == 0
            || h.vertex_count.get() > h.node_count.get()
            || u64::from(h.max_depth.get()) >= h.node_count.get()
        {
            return Err(VdtError::invalid(
                "header",
                "vertex count or depth inconsistent with the node count",
            ));
        }
        self.check_grid()
    }

    /// The page decoder computes positions as `origin + step · q` with `q ≤ GRID_STEPS`, and
    /// radii as `units · step` with fewer than 2³³ units (see `codec.rs`): with a positive
    /// step and these extremes finite, every decoded float is finite.
    fn check_grid(&self) -> Result<(), VdtError> {
        let grid = self.grid();
        let far = crate::GRID_STEPS as f32;
        let finite = grid.step > 0.0
            && (grid.step * 2f32.powi(33)).is_finite()
            && grid
                .origin
                .iter()
                .all(|&o| o.is_finite() && (o + grid.step * far).is_finite());
        if !finite {
            return Err(VdtError::invalid(
                "header",
                "grid origin or step is not finite and positive",
            ));
        }
        Ok(())
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The grid positions are stored on.
    pub fn grid(&self) -> crate::Grid {
        crate::Grid {
            origin: self.header.grid_origin.map(|c| c.get()),
            step: self.header.grid_step.get(),
        }
    }

    /// The metadata.
    pub fn metadata(&self) -> &Metadata {
        &self.metadata
    }

    /// The page directory.
    pub fn directory(&self) -> &[PageEntry] {
        &self.directory
    }

    /// The page holding node `id`.
    pub fn page_of_node(&self, id: u32) -> Result<u32, VdtError> {
        if u64::from(id) >= self.header.node_count.get() {
            return Err(VdtError::invalid(
                "node id",
                format!("{id} is out of range"),
            ));
        }
        let after = self.directory.partition_point(|p| p.first_node.get() <= id);
        Ok(after as u32 - 1)
    }

    /// Checksums, decompresses and validates page `index`.
    pub fn read_page(&self, index: u32) -> Result<Page, VdtError> {
        let mut page = Page {
            first_node: 0,
            first_triangle: 0,
            nodes: Vec::new(),
            triangles: Vec::new(),
        };
        self.read_page_into(index, &mut page)?;
        Ok(page)
    }

    /// The zstd frame of a directory entry (its range was checked on open).
    pub(crate) fn frame(&self, entry: &PageEntry) -> &[u8] {
        let start = entry.offset.get() as usize;
        &self.bytes.as_ref()[start..start + entry.compressed_length.get() as usize]
    }

    /// [`VdtFile::read_page`] into an existing page, reusing its buffers: a page cache
    /// decoding page after page allocates nothing once its buffers have grown. On error the
    /// page's contents are unspecified.
    pub fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError> {
        self.with_decompressed(index, |entry, what, decoder| {
            let h = &self.header;
            let shape = crate::codec::PageShape {
                first_node: entry.first_node.get(),
                node_count: entry.node_count.get(),
                first_triangle: entry.first_triangle.get(),
                triangle_count: entry.triangle_count.get(),
                file_nodes: h.node_count.get(),
                file_vertices: h.vertex_count.get(),
                max_depth: h.max_depth.get(),
                parts: self.metadata.part_names.len() as u64,
            };
            page.first_node = shape.first_node;
            page.first_triangle = shape.first_triangle;
            crate::codec::decode_page(
                &self.grid(),
                &decoder.raw,
                &shape,
                &mut decoder.scratch,
                &mut page.nodes,
                &mut page.triangles,
            )
            .map_err(|message| VdtError::invalid(what, message))
        })
    }

    /// Hands `look` page `index`'s stream table and streams, decompressed after its checksum
    /// is verified and not decoded into records (from the thread's reused buffer, so nothing
    /// is copied or allocated): for tools that study the page encoding, and for timing
    /// decompression apart from decoding (`vds-bench decode`).
    pub fn with_page_streams<R>(
        &self,
        index: u32,
        look: impl FnOnce(&[u8]) -> R,
    ) -> Result<R, VdtError> {
        self.with_decompressed(index, |_, _, decoder| Ok(look(&decoder.raw)))
    }

    /// Page `index`'s checksum verified and its frame decompressed into this thread's
    /// decoder, then `then` with the page's directory entry, its name for errors and the
    /// decoder.
    fn with_decompressed<R>(
        &self,
        index: u32,
        then: impl FnOnce(&PageEntry, &str, &mut PageDecoder) -> Result<R, VdtError>,
    ) -> Result<R, VdtError> {
        let entry = self
            .directory
            .get(index as usize)
            .ok_or_else(|| VdtError::invalid("page index", format!("{index} is out of range")))?;
        let what = format!("page {index}");
        let frame = self.frame(entry);
        check_sum(&what, frame, entry.checksum.get())?;
        DECODER.with(|cell| {
            let decoder = &mut *cell.borrow_mut();
            decoder
                .decompress(frame, entry.raw_length.get() as usize)
                .map_err(|e| VdtError::Decompress {
                    page: index,
                    message: e.to_string(),
                })?;
            if decoder.raw.len() != entry.raw_length.get() as usize {
                return Err(VdtError::invalid(&what, "decodes to the wrong size"));
            }
            then(entry, &what, decoder)
        })
    }

    /// Checks a decoded page's records against this file: tree links, leaf, subtri and child
    /// ranges, depths, finite non-negative bounds, cone half-angles at most π, corners and
    /// parts. Every page
    /// [`VdtFile::read_page_into`] returns already passes (the decoder checks the same as it
    /// goes, see `codec.rs`); this stand-alone pass is for pages from elsewhere, and for the
    /// tests that hold the decoder to it.
    pub fn validate_page(&self, page: &Page) -> Result<(), VdtError> {
        let what = match self.page_of_node(page.first_node) {
            Ok(index) => format!("page {index}"),
            Err(_) => "page".to_string(),
        };
        let h = &self.header;
        let limits = Limits {
            nodes: h.node_count.get(),
            vertices: h.vertex_count.get(),
            max_depth: u64::from(h.max_depth.get()),
            parts: self.metadata.part_names.len() as u64,
        };
        check_records(&what, page, &limits)
    }

    /// Decodes every page in parallel, checking every checksum and record. Returns the pages
    /// in order.
    pub fn read_all_pages(&self) -> Result<Vec<Page>, VdtError>
    where
        B: Sync,
    {
        use rayon::prelude::*;
        (0..self.directory.len() as u32)
            .into_par_iter()
            .map(|i| self.read_page(i))
            .collect()
    }
}

/// The file-wide limits every record of a page must keep.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    /// Nodes in the file.
    pub nodes: u64,
    /// Vertices (leaves) in the file.
    pub vertices: u64,
    /// The header's deepest depth.
    pub max_depth: u64,
    /// Part names in the metadata.
    pub parts: u64,
}

/// [`VdtFile::validate_page`] against explicit limits.
pub(crate) fn check_records(what: &str, page: &Page, limits: &Limits) -> Result<(), VdtError> {
    let triangle_end = u64::from(page.first_triangle) + page.triangles.len() as u64;
    for (k, n) in page.nodes.iter().enumerate() {
        let id = u64::from(page.first_node) + k as u64;
        let bad = |message: &str| VdtError::invalid(format!("{what} node {id}"), message);
        let parent = n.parent.get();
        if (id == 0) != (parent == NO_NODE) || (parent != NO_NODE && u64::from(parent) >= id) {
            return Err(bad("parent out of range"));
        }
        let children = u64::from(n.child_count);
        if children > 8
            || (children > 0
                && (u64::from(n.first_child.get()) <= id
                    || u64::from(n.first_child.get()) + children > limits.nodes))
        {
            return Err(bad("children out of range"));
        }
        if n.leaf_begin.get() >= n.leaf_end.get() || u64::from(n.leaf_end.get()) > limits.vertices {
            return Err(bad("leaf range out of range"));
        }
        if u64::from(n.depth.get()) > limits.max_depth {
            return Err(bad("depth exceeds the header's"));
        }
        let begin = u64::from(n.subtri_begin.get());
        if begin < u64::from(page.first_triangle)
            || begin + u64::from(n.subtri_count.get()) > triangle_end
        {
            return Err(bad("subtris outside the page"));
        }
        // One pass over the record's floats without early exits: this runs for every
        // node of every page read.
        let floats = [
            n.proxy[0],
            n.proxy[1],
            n.proxy[2],
            n.error_radius,
            n.sphere[0],
            n.sphere[1],
            n.sphere[2],
            n.sphere[3],
            n.cone[0],
            n.cone[1],
            n.cone[2],
            n.cone[3],
        ];
        // Finite means an exponent below all ones; the largest magnitude decides.
        let largest = floats
            .iter()
            .fold(0, |m, f| m.max(f.get().to_bits() & 0x7FFF_FFFF));
        if largest >= 0x7F80_0000 || n.error_radius.get() < 0.0 || n.sphere[3].get() < 0.0 {
            return Err(bad("non-finite or negative bound"));
        }
        // A half-angle is at most π, or negative for an empty cone (the decoder's 255 units).
        if n.cone[3].get() > std::f32::consts::PI {
            return Err(bad("cone half-angle above π"));
        }
    }
    for (k, t) in page.triangles.iter().enumerate() {
        if t.corners
            .iter()
            .any(|c| u64::from(c.get()) >= limits.vertices)
            || u64::from(t.part.get()) >= limits.parts.max(1)
        {
            return Err(VdtError::invalid(
                format!(
                    "{what} triangle {}",
                    u64::from(page.first_triangle) + k as u64
                ),
                "corner or part out of range",
            ));
        }
    }
    Ok(())
}
