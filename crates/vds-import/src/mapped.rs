//! Rows that a spilling import reads again from its input instead of copying them to its
//! spill files: a binary PLY's fixed-size vertex and face rows, in the layouts nearly every
//! such file uses (little-endian `float` coordinates; a `uchar` count with `int` or `uint`
//! indices and an optional `uint` part), and a binary STL's facets.
//!
//! Spilling copies every row into the page cache, which costs about as much as reading it (on
//! the dev VM, about 350 MB/s a core), and the input's own pages are already there: rows
//! that can be decoded again are only described (where they start in the file, how many,
//! their layout), and decoded from the input's map a run at a time whenever the weld or the
//! plan reads them, each run's pages let go behind it.
//!
//! The first read checked every row, and the file is read again later. Before each run, the
//! file's identity (device, inode, length, times of change) is compared with what it was when
//! it was mapped, so a file truncated or written since is an error naming it, not SIGBUS or
//! a scene made of both versions' rows. A write in the microseconds before a read can still
//! get through: every row is checked again as it is decoded (an error naming the row), and
//! the plan refuses a triangle whose corner the weld dropped; never a panic.

use std::ops::Range;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::ImportError;
use crate::error::{FormatError, Problem};
use crate::soup::check_position;
use crate::source::{Bytes, FileIdentity};

/// Rows decoded per parallel task: a run of rows read again (64 k rows, `spill.rs`) makes
/// 16 tasks.
const ROWS_PER_TASK: usize = 1 << 12;

/// How far around a faulting address the kernel may map a file's cached pages too: its
/// fault-around window (64 KiB by default), or the whole large folio the page cache holds
/// the page in (up to 2 MiB). Pages let go are widened by this much each side
/// ([`MappedRows::let_go`]).
const FAULT_AROUND: usize = 2 << 20;

/// What a reader found of a run of rows it decoded on a fast path: where the rows' bytes are
/// (the address of the first, and their length: a part of the input's map), the index of the
/// first in its element, the row size and the layout.
pub(crate) struct FoundRows {
    /// The address of the first row's first byte.
    pub(crate) address: usize,
    /// The rows' bytes: their count times `stride`.
    pub(crate) bytes: usize,
    /// The first row's index in its element.
    pub(crate) first_row: u64,
    /// Bytes per row.
    pub(crate) stride: usize,
    pub(crate) layout: RowLayout,
}

/// The layout of a run of rows, and what their decoded records need besides their bytes.
#[derive(Debug, Clone)]
pub(crate) enum RowLayout {
    /// Vertex rows: `x`, `y`, `z` as little-endian `f32` at these offsets.
    Positions { at: [usize; 3] },
    /// Face rows of triangles.
    Triangles(FaceRows),
    /// A binary STL's 50-byte facets: three positions each (little-endian `f32` at bytes 12,
    /// 24 and 36), and one triangle of those three vertices.
    Facets(FacetRows),
}

/// What a facet's triangle needs besides its row: the file's part, and the scene's vertices
/// and parts before the file (set by the spill).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FacetRows {
    pub(crate) part: u32,
    pub(crate) vertex_base: u32,
    pub(crate) part_base: u32,
}

/// Face rows: a `uchar` count (3 in every row) at `list_at`, followed by three little-endian
/// 32-bit indices, and the face's part.
#[derive(Debug, Clone)]
pub(crate) struct FaceRows {
    pub(crate) list_at: usize,
    /// The indices are `int`, not `uint`.
    pub(crate) signed: bool,
    /// The file's vertices: every index must be below.
    pub(crate) vertex_count: u64,
    /// Added to every index: the scene's vertices in the files before this one (set by the
    /// spill).
    pub(crate) vertex_base: u32,
    /// Added to every part: the scene's parts in the files before this one (set by the
    /// spill).
    pub(crate) part_base: u32,
    pub(crate) parts: FaceParts,
}

/// Where a face's part comes from (in the file's soup's numbering).
#[derive(Debug, Clone)]
pub(crate) enum FaceParts {
    /// Every face is in this part.
    Whole(u32),
    /// A little-endian `uint` at this offset, looked up in `table` (each value's part, set by
    /// the reader once it has read every face of the file).
    Values {
        at: usize,
        table: Arc<OnceLock<FxHashMap<u32, u32>>>,
    },
}

/// A run of rows in an input's map, decoded again on every read.
#[derive(Debug, Clone)]
pub(crate) struct MappedRows {
    pub(crate) bytes: Arc<Bytes>,
    pub(crate) path: PathBuf,
    /// What the file was when it was mapped (none for a gzipped input's decompressed copy,
    /// which has no name), checked before each read ([`MappedRows::raw`]).
    pub(crate) identity: Option<FileIdentity>,
    /// Byte offset of the first row in the map.
    pub(crate) offset: usize,
    /// The first row's index in its element (for errors).
    pub(crate) first_row: u64,
    pub(crate) rows: u64,
    pub(crate) stride: usize,
    pub(crate) layout: RowLayout,
}

impl MappedRows {
    /// The bytes of rows `range` (indices into this run), in the map, once the file is
    /// found to be as it was when it was mapped.
    ///
    /// The file may have been written since it was first read: truncated (touching the map
    /// past its end would raise SIGBUS), or changed in place (rows that each still pass
    /// their checks, but not the model the earlier passes read). Its identity (device,
    /// inode, length, times of change) is checked first, so that either is an error naming
    /// it. Only a write in the microseconds between the check and the decode can still get
    /// through, the contract every read of a mapped input accepts (`source.rs`). Reading the
    /// runs by offset instead would close the SIGBUS gap but cost the 20 M scene's plan 0.6 s
    /// more: a copy of every row, each pass over the model.
    fn raw(&self, range: &Range<u64>) -> Result<&[u8], ImportError> {
        let Bytes::Mapped(map, _) = &*self.bytes else {
            unreachable!("rows are read again only from mapped inputs");
        };
        if let Some(identity) = &self.identity {
            let now = std::fs::metadata(&self.path).map_err(|cause| self.io_error(cause))?;
            if FileIdentity::of(&now) != *identity {
                let cause = std::io::Error::other(
                    "the file changed while the build read it (it is read more than once)",
                );
                return Err(self.io_error(cause));
            }
        }
        let start = self.offset + range.start as usize * self.stride;
        let end = self.offset + range.end as usize * self.stride;
        Ok(&map[start..end])
    }

    /// Lets the map's pages of `raw` (rows of this run just decoded) go, and those within
    /// [`FAULT_AROUND`] bytes either side: a page fault maps neighbours too, which may be
    /// rows decoded and let go before, that nothing else would let go (within 512 MiB at
    /// 20 M triangles, 13 MB more stayed resident without the margin, 8 MB with 64 KiB).
    fn let_go(&self, raw: &[u8]) {
        let map: &[u8] = &self.bytes;
        let start = raw.as_ptr() as usize - map.as_ptr() as usize;
        let begin = start.saturating_sub(FAULT_AROUND);
        let end = (start + raw.len() + FAULT_AROUND).min(map.len());
        self.bytes.release(&map[begin..end]);
    }

    fn io_error(&self, cause: std::io::Error) -> ImportError {
        ImportError::Io {
            path: self.path.clone(),
            cause,
        }
    }

    /// Whether `other` continues this run: the next rows of the same map, same layout.
    pub(crate) fn continued_by(&self, other: &MappedRows) -> bool {
        let same_layout = match (&self.layout, &other.layout) {
            (RowLayout::Positions { at: a }, RowLayout::Positions { at: b }) => a == b,
            (RowLayout::Facets(a), RowLayout::Facets(b)) => a == b,
            (RowLayout::Triangles(a), RowLayout::Triangles(b)) => {
                a.list_at == b.list_at
                    && a.signed == b.signed
                    && a.vertex_count == b.vertex_count
                    && a.vertex_base == b.vertex_base
                    && a.part_base == b.part_base
                    && match (&a.parts, &b.parts) {
                        (FaceParts::Whole(p), FaceParts::Whole(q)) => p == q,
                        (
                            FaceParts::Values { at: p, table: s },
                            FaceParts::Values { at: q, table: t },
                        ) => p == q && Arc::ptr_eq(s, t),
                        _ => false,
                    }
            }
            _ => false,
        };
        Arc::ptr_eq(&self.bytes, &other.bytes)
            && self.stride == other.stride
            && same_layout
            && other.offset == self.offset + self.rows as usize * self.stride
            && other.first_row == self.first_row + self.rows
    }

    /// The error for row `row` of this run.
    fn error(&self, element: &str, row: u64, problem: Problem) -> ImportError {
        FormatError::at_element(element, self.first_row + row, problem).in_file(&self.path)
    }

    /// Decodes rows `range` of a vertex run (or a run of STL facets, three positions each)
    /// into `out`.
    pub(crate) fn positions(
        &self,
        range: Range<u64>,
        out: &mut Vec<[f32; 3]>,
    ) -> Result<(), ImportError> {
        let raw = self.raw(&range)?;
        let stride = self.stride;
        let failed = match &self.layout {
            RowLayout::Positions { at } => {
                let at = *at;
                self.decode_rows(raw, out, 1, |rows, out| {
                    for (k, (row, p)) in rows.chunks_exact(stride).zip(out).enumerate() {
                        *p = at.map(|a| f32::from_le_bytes(four(&row[a..])));
                        check_position(*p).map_err(|problem| (k, problem))?;
                    }
                    Ok(())
                })
            }
            RowLayout::Facets(_) => self.decode_rows(raw, out, 3, |rows, out| {
                for (k, (row, corners)) in
                    rows.chunks_exact(stride).zip(out.chunks_mut(3)).enumerate()
                {
                    for (c, p) in corners.iter_mut().enumerate() {
                        *p = [0, 1, 2]
                            .map(|i| f32::from_le_bytes(four(&row[12 + 12 * c + 4 * i..])));
                        check_position(*p).map_err(|problem| (k, problem))?;
                    }
                }
                Ok(())
            }),
            RowLayout::Triangles(_) => unreachable!("positions are not read from face rows"),
        };
        if let Err((bad, problem)) = failed {
            let element = match self.layout {
                RowLayout::Facets(_) => "triangle",
                _ => "vertex",
            };
            return Err(self.error(element, range.start + bad as u64, problem));
        }
        self.let_go(raw);
        Ok(())
    }

    /// Decodes rows `range` of a face run (or a run of STL facets) into `[a, b, c, part]`
    /// records with the scene's indices and parts, into `out`.
    pub(crate) fn triangles(
        &self,
        range: Range<u64>,
        out: &mut Vec<[u32; 4]>,
    ) -> Result<(), ImportError> {
        let faces = match &self.layout {
            RowLayout::Triangles(faces) => faces,
            RowLayout::Facets(facets) => {
                // Facet `r` of the file is its vertices `3r`, `3r + 1`, `3r + 2`: nothing
                // to read.
                let first = (self.first_row + range.start) as u32;
                out.clear();
                out.extend((first..first + (range.end - range.start) as u32).map(|r| {
                    // Wrapping as the spill's indices do: inputs past 2³² vertices are
                    // refused before their records are read.
                    let v = facets.vertex_base.wrapping_add(r.wrapping_mul(3));
                    let [a, b, c] = [0, 1, 2].map(|k| v.wrapping_add(k));
                    [a, b, c, facets.part_base + facets.part]
                }));
                return Ok(());
            }
            RowLayout::Positions { .. } => unreachable!("triangles are not read from vertex rows"),
        };
        let raw = self.raw(&range)?;
        let stride = self.stride;
        let failed = match &faces.parts {
            FaceParts::Whole(part) => self.decode_rows(raw, out, 1, |rows, out| {
                faces.decode(rows, stride, out, |_| Ok(*part))
            }),
            FaceParts::Values { at, table } => {
                let Some(table) = table.get() else {
                    let problem = Problem::Syntax("the faces' parts were never read".into());
                    return Err(self.error("face", range.start, problem));
                };
                self.decode_rows(raw, out, 1, |rows, out| {
                    // Faces of one part come in runs: the last value's part is kept.
                    let mut last = None;
                    faces.decode(rows, stride, out, |row| {
                        let value = u32::from_le_bytes(four(&row[*at..]));
                        match last {
                            Some((v, part)) if v == value => Ok(part),
                            _ => {
                                let part = *table.get(&value).ok_or_else(|| {
                                    Problem::Syntax(format!(
                                        "part {value} was not in the file when it was first read"
                                    ))
                                })?;
                                last = Some((value, part));
                                Ok(part)
                            }
                        }
                    })
                })
            }
        };
        if let Err((bad, problem)) = failed {
            return Err(self.error("face", range.start + bad as u64, problem));
        }
        self.let_go(raw);
        Ok(())
    }

    /// Decodes the rows of `raw` (this run's, in the map) into `out`, `per_row` records a
    /// row, a share of [`ROWS_PER_TASK`] rows per task with `decode(rows, records)`, which
    /// returns the first row it failed on and why; the first failing row in file order, if
    /// any.
    fn decode_rows<T: Copy + Default + Send>(
        &self,
        raw: &[u8],
        out: &mut Vec<T>,
        per_row: usize,
        decode: impl Fn(&[u8], &mut [T]) -> Result<(), (usize, Problem)> + Sync,
    ) -> Result<(), (usize, Problem)> {
        let rows = raw.len() / self.stride;
        out.clear();
        out.resize(rows * per_row, T::default());
        let decoded = raw
            .par_chunks(self.stride * ROWS_PER_TASK)
            .zip(out.par_chunks_mut(ROWS_PER_TASK * per_row))
            .try_for_each(|(rows, out)| decode(rows, out));
        // Tasks stop at whichever failure they meet first: the first in file order is found
        // again on one thread (rows fail only in a file changed since it was first read).
        decoded.or_else(|_| decode(raw, out))
    }
}

impl FaceRows {
    /// Decodes the face rows of `rows` into `out`, with `part` reading each row's part; the
    /// first row that fails is returned with its index and problem.
    #[inline]
    fn decode(
        &self,
        rows: &[u8],
        stride: usize,
        out: &mut [[u32; 4]],
        mut part: impl FnMut(&[u8]) -> Result<u32, Problem>,
    ) -> Result<(), (usize, Problem)> {
        for (k, (row, record)) in rows.chunks_exact(stride).zip(out).enumerate() {
            if row[self.list_at] != 3 {
                let problem = "no longer a triangle: the file changed while it was read";
                return Err((k, Problem::Syntax(problem.into())));
            }
            for c in 0..3 {
                let bytes = four(&row[self.list_at + 1 + 4 * c..]);
                let index = if self.signed {
                    i64::from(i32::from_le_bytes(bytes))
                } else {
                    i64::from(u32::from_le_bytes(bytes))
                };
                if index < 0 || index as u64 >= self.vertex_count {
                    let vertex_count = self.vertex_count;
                    return Err((
                        k,
                        Problem::IndexOutOfRange {
                            index,
                            vertex_count,
                        },
                    ));
                }
                record[c] = self.vertex_base.wrapping_add(index as u32);
            }
            record[3] = self.part_base + part(row).map_err(|problem| (k, problem))?;
        }
        Ok(())
    }
}

/// The first four bytes of `bytes`.
fn four(bytes: &[u8]) -> [u8; 4] {
    bytes[..4].try_into().expect("4 bytes")
}
