//! The `.vdt` vertex-tree file of vds: one file per scene, read a page at a time.
//!
//! ```text
//! VDT := HEADER (128 B) METADATA (rkyv) DIRECTORY (PageEntry × page_count) PAGE*
//! PAGE := zstd( stream table, 11 varint streams of node and triangle columns )
//! ```
//!
//! The byte-level specification is `docs/format.md`. [`write_file`] lays a tree out in pages
//! and writes it atomically and deterministically; [`VdtFile`] opens one (header, metadata
//! and directory only), validating everything before use, and decodes pages on demand.

#![deny(missing_docs)]

mod codec;
mod error;
mod figures;
#[cfg(feature = "fuzzing")]
pub mod fuzzing;
mod grid;
pub mod layout;
mod metadata;
pub mod output;
mod read;
mod write;

pub use error::{BoundViolation, VdtError};
pub use figures::{StatedField, TreeFigures};
pub use grid::{GRID_STEPS, Grid};
pub use layout::{
    FLAG_TWO_SIDED_CONE, HEADER_BYTES, Header, NO_NODE, NODE_BYTES, NodeRecord,
    OLDEST_READABLE_VERSION, PageEntry, TRIANGLE_BYTES, TriangleRecord, VDT_MAGIC, VDT_VERSION,
};
pub use metadata::{BuildInfo, InputInfo, MAX_PARTS, Metadata, NO_PART, PartInfo};
pub use output::{AtomicFile, OutputError, resolve_output, same_file, write_atomically};
pub use read::{MAX_COMPRESSION_RATIO, MAX_PAGE_RAW_BYTES, Page, VdtFile};
pub use write::{
    DEFAULT_PAGE_BYTES, DEFAULT_ZSTD_LEVEL, DETACHED_ROOT, EncodedPage, EncodedPageSummary,
    FileFigures, NodeSource, PageLayout, TreeContent, WriteOptions, WriteReport, attach_region,
    attached_id, detached_id, encode, encode_detached_region, encode_page_frame, encode_pages,
    file_head, in_top_with_children, region_leaves, write_file,
};
