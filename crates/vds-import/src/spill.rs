//! Import without holding the model: the readers spill the soup to files as they read
//! ([`FileSpill`]), but for the rows of a mapped binary PLY or STL, which are read again from
//! the input ([`crate::mapped`]); the exact weld runs over those records with one bucket of
//! positions in memory at a time ([`SoupFiles::weld`]). The result, a [`SpilledScene`], keeps
//! in memory only what a sharded build's plan looks up at random: the welded positions (12
//! bytes per welded vertex) and each input vertex's welded index (4 bytes per input vertex);
//! the triangles stay on disk, in the spill file or the input, and are read in runs.
//!
//! The weld gives the scene [`crate::weld`] gives with [`crate::Weld::Exact`], vertex for
//! vertex and triangle for triangle (tested): each input vertex's representative is the lowest
//! index at its position, found per bucket of a position hash by the in-memory weld's own
//! [`crate::weld::exact_representatives`] (equal positions share a bucket, and a bucket holds
//! its vertices in input order, so the lowest index in a bucket is the lowest overall); then
//! the same passes as in memory, over the files.
//!
//! Files are unnamed temporary files in the folder the caller names (not `TMPDIR`, which may
//! be memory); they vanish with the scene, or with the process.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use crate::mapped::{FoundRows, MappedRows, RowLayout};
use crate::source::Bytes;
use crate::{ImportError, ImportStats, PartInfo};

/// Positions per bucket of the weld: a bucket's resolution holds about 50 bytes per vertex.
const BUCKET_VERTICES: u64 = 1 << 20;
/// The most buckets (each an open file with a buffer of [`BUCKET_BUFFER`] bytes while the
/// positions are scattered): 2³² vertices make buckets of 8 M vertices, 0.4 GB to resolve.
const MAX_BUCKETS: u64 = 512;
const BUCKET_BUFFER: usize = 64 << 10;
/// Positions the weld remembers while it scatters (16 bytes each): see [`representatives`].
const RECENT_POSITIONS: usize = 1 << 16;
/// A bucket's vertices whose representatives a task writes back ([`representatives`]).
const WRITE_BACK_SHARE: usize = 1 << 15;
/// Triangles or vertices read from a spill file at a time (4 MB of triangles).
const RUN: usize = 1 << 18;
/// Rows decoded from an input's map at a time ([`crate::mapped`]): the map's pages of a
/// run are resident until it is decoded (a budgeted build counts them), about 1 MB of a
/// PLY's faces. (Letting each task's rows go as soon as it had decoded them instead left
/// more resident: the kernel maps a fault's neighbours, which may be rows already let go.)
const MAPPED_RUN: u64 = 1 << 16;

/// Where a soup's records lie, run by run in order: in a spill file (the next records of
/// it) or in an input's map ([`crate::mapped`]).
#[derive(Debug, Default)]
struct Segments {
    list: Vec<Segment>,
    /// Records in the spill file so far.
    spilled: u64,
}

#[derive(Debug)]
enum Segment {
    /// `count` records of the spill file from record `at`.
    Spilled {
        at: u64,
        count: u64,
    },
    Mapped(MappedRows),
}

impl Segments {
    fn push_spilled(&mut self, count: u64) {
        if count == 0 {
            return;
        }
        match self.list.last_mut() {
            Some(Segment::Spilled { count: last, .. }) => *last += count,
            _ => self.list.push(Segment::Spilled {
                at: self.spilled,
                count,
            }),
        }
        self.spilled += count;
    }

    fn push_mapped(&mut self, rows: MappedRows) {
        if rows.rows == 0 {
            return;
        }
        if let Some(Segment::Mapped(last)) = self.list.last_mut()
            && last.continued_by(&rows)
        {
            last.rows += rows.rows;
            return;
        }
        self.list.push(Segment::Mapped(rows));
    }

    /// Hands every record to `each` in runs of at most [`RUN`], in order: those of `file`
    /// (the spill file) read from it, the others decoded from their maps by `decode`.
    fn read_runs<T: bytemuck::Pod, E>(
        &self,
        file: &File,
        decode: impl Fn(&MappedRows, std::ops::Range<u64>, &mut Vec<T>) -> Result<(), ImportError>,
        mut each: impl FnMut(&[T]) -> Result<(), E>,
    ) -> Result<(), RunError<E>> {
        let mut buffer = Vec::new();
        for run in &self.list {
            match run {
                Segment::Spilled { at, count } => {
                    read_runs_at(file, *at, *count, &mut buffer, |records| {
                        each(records).map_err(RunError::Caller)
                    })?
                }
                Segment::Mapped(rows) => {
                    let mut done = 0;
                    while done < rows.rows {
                        let n = (rows.rows - done).min(MAPPED_RUN);
                        decode(rows, done..done + n, &mut buffer).map_err(RunError::Import)?;
                        each(&buffer).map_err(RunError::Caller)?;
                        done += n;
                    }
                }
            }
        }
        Ok(())
    }
}

/// A soup's positions or triangles: a spill file and where each run lies.
#[derive(Debug)]
struct Records {
    file: File,
    segments: Segments,
}

impl Records {
    /// Every position in order, in runs.
    fn positions<E>(
        &self,
        each: impl FnMut(&[[f32; 3]]) -> Result<(), E>,
    ) -> Result<(), RunError<E>> {
        self.segments
            .read_runs(&self.file, MappedRows::positions, each)
    }

    /// Every triangle in order as `[a, b, c, part]` with the scene's indices and parts, in
    /// runs.
    fn triangles<E>(
        &self,
        each: impl FnMut(&[[u32; 4]]) -> Result<(), E>,
    ) -> Result<(), RunError<E>> {
        self.segments
            .read_runs(&self.file, MappedRows::triangles, each)
    }
}

/// A soup's vertices and triangles on disk: positions (`[f32; 3]`) and triangles with their
/// part (`[a, b, c, part]`), in native byte order (the files never leave the process), and
/// where the rows read again from the inputs lie between them.
#[derive(Debug)]
pub struct SoupFiles {
    folder: PathBuf,
    positions: BufWriter<File>,
    triangles: BufWriter<File>,
    /// Where each run of vertices and triangles is: in the spill files, or in an input's map.
    position_runs: Segments,
    triangle_runs: Segments,
    vertex_count: u64,
    triangle_count: u64,
    part_names: Vec<String>,
    parts: Vec<PartInfo>,
    short_faces_dropped: u64,
    warnings: Vec<String>,
}

impl SoupFiles {
    /// Empty spill files in `folder`.
    pub fn create(folder: &Path) -> Result<SoupFiles, ImportError> {
        let file = || {
            tempfile::tempfile_in(folder)
                .map(|f| BufWriter::with_capacity(1 << 20, f))
                .map_err(|cause| io_error(folder, cause))
        };
        Ok(SoupFiles {
            folder: folder.to_path_buf(),
            positions: file()?,
            triangles: file()?,
            position_runs: Segments::default(),
            triangle_runs: Segments::default(),
            vertex_count: 0,
            triangle_count: 0,
            part_names: Vec::new(),
            parts: Vec::new(),
            short_faces_dropped: 0,
            warnings: Vec::new(),
        })
    }

    /// Vertices spilled so far.
    pub fn vertex_count(&self) -> u64 {
        self.vertex_count
    }

    /// Triangles spilled so far.
    pub fn triangle_count(&self) -> u64 {
        self.triangle_count
    }

    /// A spill for the next input file, whose soup numbers its vertices and parts from 0.
    pub(crate) fn for_file(self, rows: usize) -> FileSpill {
        FileSpill {
            rows,
            vertex_base: self.vertex_count,
            part_base: self.part_names.len() as u32,
            spilled: (0, 0),
            files: self,
            error: None,
            input: None,
            released_to: 0,
        }
    }
}

/// One input file's spill: its soup's vertices and triangles go to the [`SoupFiles`] with
/// their indices moved past the files read before.
#[derive(Debug)]
pub(crate) struct FileSpill {
    /// Rows a streaming reader reads between spills.
    pub(crate) rows: usize,
    files: SoupFiles,
    vertex_base: u64,
    part_base: u32,
    /// This file's vertices and triangles handed over so far (spilled, or kept as rows to
    /// read again).
    spilled: (usize, usize),
    /// The first write error; nothing is written after it.
    error: Option<std::io::Error>,
    /// The file's mapped bytes, whose pages the reader may let go of as it goes, and its
    /// path (for the errors of rows read again from the map).
    pub(crate) input: Option<(Arc<Bytes>, PathBuf)>,
    /// The address up to which the input has been released.
    released_to: usize,
}

impl FileSpill {
    pub(crate) fn spilled(&self) -> (usize, usize) {
        self.spilled
    }

    /// The folder the spill files are in.
    pub(crate) fn folder(&self) -> &Path {
        &self.files.folder
    }

    /// Writes out and clears the soup's arrays (keeping their memory for the next rows).
    pub(crate) fn take(
        &mut self,
        positions: &mut Vec<[f32; 3]>,
        triangles: &mut Vec<[u32; 3]>,
        parts: &mut Vec<u32>,
    ) {
        self.spilled.0 += positions.len();
        self.spilled.1 += triangles.len();
        if self.error.is_none() {
            let written = self.write(positions, triangles, parts);
            self.error = written.err();
        }
        positions.clear();
        triangles.clear();
        parts.clear();
    }

    fn write(
        &mut self,
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
        parts: &[u32],
    ) -> std::io::Result<()> {
        let files = &mut self.files;
        files.positions.write_all(bytemuck::cast_slice(positions))?;
        files.vertex_count += positions.len() as u64;
        files.position_runs.push_spilled(positions.len() as u64);
        // The soup's indices and parts count from this file's first; the files' from the
        // scene's. Inputs of more than 2³² vertices together wrap here, and the importer
        // refuses them once the file is read (`check_file`), before the records are used.
        let base = self.vertex_base as u32;
        // A run at a time: a reader that spills only at the end of its file hands it whole.
        let mut records: Vec<[u32; 4]> = Vec::new();
        for (triangles, parts) in triangles.chunks(RUN).zip(parts.chunks(RUN)) {
            records.clear();
            records.par_extend(triangles.par_iter().zip(parts).map(|(t, &part)| {
                let [a, b, c] = t.map(|v| v.wrapping_add(base));
                [a, b, c, part + self.part_base]
            }));
            files.triangles.write_all(bytemuck::cast_slice(&records))?;
        }
        files.triangle_count += triangles.len() as u64;
        files.triangle_runs.push_spilled(triangles.len() as u64);
        Ok(())
    }

    /// Takes rows the reader decoded on a fast path (`found`, now in the soup's arrays) as
    /// runs read again from the input's map rather than spilled, when the input is mapped
    /// and the rows lie in it and make all the soup holds (`held`: its vertices and
    /// triangles): returns whether it did (the caller then clears the arrays); otherwise the
    /// rows are spilled as usual.
    pub(crate) fn take_mapped(&mut self, found: FoundRows, held: (usize, usize)) -> bool {
        let Some((input, path)) = &self.input else {
            return false;
        };
        let Bytes::Mapped(map, identity) = &**input else {
            return false;
        };
        // Rows, and the vertices and triangles they make, which the soup must hold.
        let (rows, made) = match &found.layout {
            RowLayout::Positions { .. } => (held.0, (held.0, 0)),
            RowLayout::Triangles(_) => (held.1, (0, held.1)),
            RowLayout::Facets(_) => (held.1, (3 * held.1, held.1)),
        };
        let base = map.as_ptr() as usize;
        let start = found.address;
        if self.error.is_some()
            || found.stride == 0
            || start < base
            || start + found.bytes > base + map.len()
            || found.bytes != rows * found.stride
            || made != held
        {
            return false;
        }
        let mut layout = found.layout;
        match &mut layout {
            RowLayout::Positions { .. } => {}
            RowLayout::Triangles(faces) => {
                faces.vertex_base = self.vertex_base as u32;
                faces.part_base = self.part_base;
            }
            RowLayout::Facets(facets) => {
                facets.vertex_base = self.vertex_base as u32;
                facets.part_base = self.part_base;
            }
        }
        let rows = MappedRows {
            bytes: input.clone(),
            path: path.clone(),
            identity: *identity,
            offset: start - base,
            first_row: found.first_row,
            rows: rows as u64,
            stride: found.stride,
            layout,
        };
        let files = &mut self.files;
        self.spilled.0 += made.0;
        self.spilled.1 += made.1;
        files.vertex_count += made.0 as u64;
        files.triangle_count += made.1 as u64;
        match rows.layout {
            RowLayout::Positions { .. } => files.position_runs.push_mapped(rows),
            RowLayout::Triangles(_) => files.triangle_runs.push_mapped(rows),
            RowLayout::Facets(_) => {
                files.position_runs.push_mapped(rows.clone());
                files.triangle_runs.push_mapped(rows);
            }
        }
        true
    }

    /// Lets the input map drop the pages of `bytes` (the input up to where the reader is)
    /// from this process's memory; only what follows the last call's end is released again.
    pub(crate) fn done_with_input(&mut self, bytes: &[u8]) {
        if let Some((input, _)) = &self.input {
            let end = bytes.as_ptr() as usize + bytes.len();
            let start = (bytes.as_ptr() as usize).max(self.released_to);
            if start < end {
                let skip = start - bytes.as_ptr() as usize;
                input.release(&bytes[skip..]);
                self.released_to = end;
            }
        }
    }

    /// The spill files back, with this file's soup's parts and counts added (its vertices and
    /// triangles spilled), or the first write error.
    pub(crate) fn finish(self, soup: crate::MeshSoup) -> Result<SoupFiles, std::io::Error> {
        let mut files = self.files;
        if let Some(error) = self.error {
            return Err(error);
        }
        let part_base = self.part_base;
        files.part_names.extend(soup.part_names);
        files.parts.extend(soup.parts.into_iter().map(|p| PartInfo {
            parent: p.parent.map(|q| q + part_base),
            color: p.color,
        }));
        files.short_faces_dropped += soup.short_faces_dropped;
        files.warnings.extend(soup.warnings);
        Ok(files)
    }
}

/// A welded scene whose triangles stay on disk (in the spill file, or in the inputs): what
/// [`crate::spill_files`] returns.
#[derive(Debug)]
pub struct SpilledScene {
    /// Welded positions, in input order of their first vertex, each used by a triangle (the
    /// welded [`crate::Scene::positions`]).
    pub positions: Vec<[f32; 3]>,
    /// Part names.
    pub part_names: Vec<String>,
    /// Per part, its parent and colour.
    pub parts: Vec<PartInfo>,
    /// What import and welding did.
    pub stats: ImportStats,
    /// What could not be read but cost only colours.
    pub warnings: Vec<String>,
    /// Triangles after welding.
    pub triangle_count: u64,
    /// Each input vertex's welded index (`u32::MAX` for one no triangle keeps).
    welded_index: Vec<u32>,
    /// The soup's triangles and parts (input indices), spilled or read again from inputs.
    triangles: Records,
    folder: PathBuf,
}

impl SpilledScene {
    /// Calls `each(first, triangles, parts)` for runs of the welded scene's triangles in order
    /// (`first` is the index of the run's first triangle): the welded
    /// [`crate::Scene::triangles`] and [`crate::Scene::triangle_parts`], a run at a time.
    pub fn for_each_triangle_run<E>(
        &self,
        mut each: impl FnMut(u64, &[[u32; 3]], &[u32]) -> Result<(), E>,
        io: impl Fn(ImportError) -> E,
    ) -> Result<(), E> {
        let mut first = 0u64;
        let mut triangles = Vec::with_capacity(RUN);
        let mut parts = Vec::with_capacity(RUN);
        let read = self.triangles.triangles(|records| {
            triangles.clear();
            parts.clear();
            for r in records {
                let t = [r[0], r[1], r[2]].map(|v| self.welded_index[v as usize]);
                if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                    // A corner the weld found no triangle of: rows read again from an input
                    // that changed between the passes unnoticed.
                    if t.contains(&u32::MAX) {
                        return Err(io(changed_between_passes(&self.folder)));
                    }
                    triangles.push(t);
                    parts.push(r[3]);
                }
            }
            each(first, &triangles, &parts)?;
            first += triangles.len() as u64;
            Ok(())
        });
        read.map_err(|e| match e {
            RunError::Io(cause) => io(io_error(&self.folder, cause)),
            RunError::Import(e) => io(e),
            RunError::Caller(e) => e,
        })
    }

    /// Reads the whole scene into memory (for tests and small inputs).
    pub fn to_scene(&self) -> Result<crate::Scene, ImportError> {
        let mut triangles = Vec::new();
        let mut triangle_parts = Vec::new();
        self.for_each_triangle_run(
            |_, t, p| {
                triangles.extend_from_slice(t);
                triangle_parts.extend_from_slice(p);
                Ok(())
            },
            |e| e,
        )?;
        Ok(crate::Scene {
            positions: self.positions.clone(),
            triangles,
            triangle_parts,
            part_names: self.part_names.clone(),
            parts: self.parts.clone(),
            stats: self.stats,
            warnings: self.warnings.clone(),
        })
    }
}

/// Why reading runs of records stopped: the spill file, a row read again from an input, or
/// the caller.
enum RunError<E> {
    Io(std::io::Error),
    Import(ImportError),
    Caller(E),
}

impl<E> RunError<E> {
    /// The error, with an I/O error of the spill files in `folder` made an [`ImportError`].
    fn into_error(self, folder: &Path) -> E
    where
        E: From<ImportError>,
    {
        match self {
            RunError::Io(cause) => io_error(folder, cause).into(),
            RunError::Import(e) => e.into(),
            RunError::Caller(e) => e,
        }
    }
}

/// Reads `count` records of `T` from record `at` of `file` into `buffer` and hands them to
/// `each` in runs of at most [`RUN`].
fn read_runs_at<T: bytemuck::Pod, E>(
    file: &File,
    at: u64,
    count: u64,
    buffer: &mut Vec<T>,
    mut each: impl FnMut(&[T]) -> Result<(), RunError<E>>,
) -> Result<(), RunError<E>> {
    let size = size_of::<T>() as u64;
    let mut done = 0u64;
    while done < count {
        let n = (count - done).min(RUN as u64) as usize;
        buffer.resize(n, T::zeroed());
        let bytes = bytemuck::cast_slice_mut(&mut buffer[..n]);
        file.read_exact_at(bytes, (at + done) * size)
            .map_err(RunError::Io)?;
        each(&buffer[..n])?;
        done += n as u64;
    }
    Ok(())
}

/// Reads the `count` records of `T` of `file` (a bucket file) and hands them to `each` in
/// runs of at most [`RUN`].
fn read_runs<T: bytemuck::Pod>(
    file: &File,
    count: u64,
    mut each: impl FnMut(&[T]),
) -> std::io::Result<()> {
    let mut buffer = Vec::new();
    read_runs_at(file, 0, count, &mut buffer, |run| {
        each(run);
        Ok::<(), RunError<()>>(())
    })
    .map_err(|e| match e {
        RunError::Io(cause) => cause,
        _ => unreachable!("only reading the file fails"),
    })
}

/// The error for records that differ between two reads of the model.
fn changed_between_passes(folder: &Path) -> ImportError {
    let cause = std::io::Error::other("an input changed while the build read it more than once");
    io_error(folder, cause)
}

fn io_error(folder: &Path, cause: std::io::Error) -> ImportError {
    ImportError::Io {
        path: folder.to_path_buf(),
        cause,
    }
}

#[cfg(test)]
impl SoupFiles {
    /// Forgets what the inputs of the rows read again were when they were mapped, so that a
    /// test can change a file under them and reach the checks of the rows themselves (which
    /// a change the identity check misses, in the microseconds before a read, meets).
    fn forget_identities(&mut self) {
        for segments in [&mut self.position_runs, &mut self.triangle_runs] {
            for segment in &mut segments.list {
                if let Segment::Mapped(rows) = segment {
                    rows.identity = None;
                }
            }
        }
    }
}

impl SoupFiles {
    /// Welds the spilled soup exactly, as [`crate::weld`] with [`crate::Weld::Exact`] does.
    pub fn weld(self) -> Result<SpilledScene, ImportError> {
        self.weld_in_buckets_of(BUCKET_VERTICES, RECENT_POSITIONS, WRITE_BACK_SHARE)
    }

    /// [`SoupFiles::weld`] with buckets of about `bucket_vertices` positions, remembering
    /// `recent` positions (a power of two) while scattering, and writing each bucket's
    /// representatives back in shares of `share` vertices.
    fn weld_in_buckets_of(
        self,
        bucket_vertices: u64,
        recent: usize,
        share: usize,
    ) -> Result<SpilledScene, ImportError> {
        let folder = self.folder.clone();
        let io = |cause| io_error(&folder, cause);
        let positions = Records {
            file: self
                .positions
                .into_inner()
                .map_err(|e| io(e.into_error()))?,
            segments: self.position_runs,
        };
        let triangles = Records {
            file: self
                .triangles
                .into_inner()
                .map_err(|e| io(e.into_error()))?,
            segments: self.triangle_runs,
        };
        let vertices = self.vertex_count;
        let input_triangles = self.triangle_count;

        let representative = representatives(
            &positions,
            vertices,
            bucket_vertices,
            recent,
            share,
            &folder,
        )?;
        let distinct = representative
            .par_iter()
            .enumerate()
            .filter(|&(i, &r)| i as u32 == r)
            .count() as u64;

        // Which representatives a triangle that stays uses, and how many triangles go; each
        // run on every core (a bit is set by whichever triangle reaches it first: a load
        // first, so that the vertex's later triangles, about five, take no atomic write).
        let used: Vec<AtomicU64> = (0..(vertices as usize).div_ceil(64))
            .map(|_| AtomicU64::new(0))
            .collect();
        let mut degenerate = 0u64;
        triangles
            .triangles(|records| {
                degenerate += records
                    .par_chunks(1 << 12)
                    .map(|chunk| {
                        let mut dropped = 0u64;
                        for r in chunk {
                            let [a, b, c] = [r[0], r[1], r[2]].map(|v| representative[v as usize]);
                            if a != b && b != c && a != c {
                                for v in [a, b, c] {
                                    let (word, bit) = (&used[v as usize / 64], 1 << (v % 64));
                                    if word.load(Ordering::Relaxed) & bit == 0 {
                                        word.fetch_or(bit, Ordering::Relaxed);
                                    }
                                }
                            } else {
                                dropped += 1;
                            }
                        }
                        dropped
                    })
                    .sum::<u64>();
                Ok::<(), ImportError>(())
            })
            .map_err(|e| e.into_error(&folder))?;
        let used: Vec<u64> = used.into_iter().map(AtomicU64::into_inner).collect();

        // New indices for the used representatives in input order, and their positions; then
        // every vertex's index through its representative, in place: a representative is
        // the lowest index of its group, so it comes first and is already renumbered.
        let mut welded_index = representative;
        // Room for the kept positions at once (a bit of `used` is set only for a
        // representative a triangle keeps): grown by doubling, they were copied and faulted
        // in again, 0.2 s of the 20 M scene's plan.
        let kept: usize = used.iter().map(|word| word.count_ones() as usize).sum();
        let mut welded = Vec::with_capacity(kept);
        let mut v = 0usize;
        positions
            .positions(|run| {
                for &p in run {
                    let r = welded_index[v] as usize;
                    welded_index[v] = if r == v {
                        if used[v / 64] & (1 << (v % 64)) != 0 {
                            welded.push(p);
                            (welded.len() - 1) as u32
                        } else {
                            u32::MAX
                        }
                    } else {
                        welded_index[r]
                    };
                    v += 1;
                }
                Ok::<(), ImportError>(())
            })
            .map_err(|e| e.into_error(&folder))?;
        drop(used);
        drop(positions);
        debug_assert_eq!(welded.len(), kept, "the kept representatives");
        let kept = kept as u64;
        Ok(SpilledScene {
            positions: welded,
            part_names: self.part_names,
            parts: self.parts,
            stats: ImportStats {
                input_vertices: vertices,
                input_triangles,
                welded_vertices: vertices - distinct,
                degenerate_triangles_dropped: degenerate,
                short_faces_dropped: self.short_faces_dropped,
                unreferenced_vertices_dropped: distinct - kept,
            },
            warnings: self.warnings,
            triangle_count: input_triangles - degenerate,
            welded_index,
            triangles,
            folder,
        })
    }
}

/// Each vertex's lowest-index vertex at the same position: the positions are scattered by a
/// hash of their bits into bucket files (in input order within each), and each bucket is
/// resolved in memory by the in-memory weld.
///
/// While scattering, the last vertex to miss at each of `recent` slots (by hash) is
/// remembered: a vertex at its position is a later copy of it, and goes to no bucket; at the
/// end it takes that vertex's representative. A soup's copies (an STL repeats each vertex
/// about six times) mostly end there, and no position repeated millions of times fills a
/// bucket (which would hold about 50 bytes per vertex as it is resolved).
fn representatives(
    positions: &Records,
    vertices: u64,
    bucket_vertices: u64,
    recent: usize,
    share: usize,
    folder: &Path,
) -> Result<Vec<u32>, ImportError> {
    let io = |cause| io_error(folder, cause);
    let buckets = vertices.div_ceil(bucket_vertices).clamp(1, MAX_BUCKETS);
    if buckets == 1 {
        let mut all = Vec::with_capacity(vertices as usize);
        positions
            .positions(|run| {
                all.extend_from_slice(run);
                Ok::<(), ImportError>(())
            })
            .map_err(|e| e.into_error(folder))?;
        return Ok(crate::weld::exact_representatives(&all));
    }
    let mut representative = vec![0u32; vertices as usize];
    // Bucket files of `[x, y, z, index]` records.
    let mut files = (0..buckets)
        .map(|_| {
            tempfile::tempfile_in(folder)
                .map(|f| BufWriter::with_capacity(BUCKET_BUFFER, f))
                .map_err(io)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut counts = vec![0u64; buckets as usize];
    // Slots of (position bits with `-0.0` as `0.0`, vertex); NaN bits match no position.
    let mut seen = vec![([u32::MAX; 3], 0u32); recent];
    let slot_shift = 64 - recent.trailing_zeros();
    let mut copies = vec![0u64; (vertices as usize).div_ceil(64)];
    // Counted in `u64`: the inputs may hold exactly 2³² vertices.
    let mut index = 0u64;
    positions
        .positions(|run| {
            for p in run {
                let hash = crate::weld::position_hash(p);
                let key = p.map(|c| (c + 0.0).to_bits());
                let slot = &mut seen[hash.checked_shr(slot_shift).unwrap_or(0) as usize];
                if slot.0 == key {
                    representative[index as usize] = slot.1;
                    copies[index as usize / 64] |= 1 << (index % 64);
                    index += 1;
                    continue;
                }
                *slot = (key, index as u32);
                // The bucket from the hash's bits below its top 12, which pick the in-memory
                // weld's own buckets: from the same bits, a bucket of ours would fall in one or
                // two of those, resolved on one thread with a table out of cache.
                let b = (u128::from(hash << 12) * u128::from(buckets)) >> 64;
                let bits = p.map(f32::to_bits);
                let record = [bits[0], bits[1], bits[2], index as u32];
                files[b as usize].write_all(bytemuck::cast_slice(&record))?;
                counts[b as usize] += 1;
                index += 1;
            }
            Ok::<(), std::io::Error>(())
        })
        .map_err(|e| match e {
            RunError::Io(cause) | RunError::Caller(cause) => io(cause),
            RunError::Import(e) => e,
        })?;
    for (file, count) in files.into_iter().zip(counts) {
        let file = file.into_inner().map_err(|e| io(e.into_error()))?;
        let mut bucket = Vec::with_capacity(count as usize);
        let mut global = Vec::with_capacity(count as usize);
        read_runs(&file, count, |run: &[[u32; 4]]| {
            for r in run {
                bucket.push([r[0], r[1], r[2]].map(f32::from_bits));
                global.push(r[3]);
            }
        })
        .map_err(io)?;
        drop(file);
        let local = crate::weld::exact_representatives(&bucket);
        drop(bucket);
        // Each vertex's representative, written at random into an array of 4 bytes a vertex,
        // on every core (on one thread, the 200 M scene's plan took 30.5-31.0 s, and
        // 29.3-30.1 s so): the bucket's vertices are in input order, so shares of them cover
        // disjoint ranges of the array.
        let mut rest = representative.as_mut_slice();
        let mut skipped = 0usize;
        let mut shares = Vec::new();
        for (ids, locals) in global.chunks(share).zip(local.chunks(share)) {
            let end = *ids.last().expect("shares are not empty") as usize + 1;
            let (share, tail) = std::mem::take(&mut rest).split_at_mut(end - skipped);
            shares.push((skipped, share, ids, locals));
            rest = tail;
            skipped = end;
        }
        shares
            .into_par_iter()
            .for_each(|(base, share, ids, locals)| {
                for (&v, &r) in ids.iter().zip(locals) {
                    share[v as usize - base] = global[r as usize];
                }
            });
    }
    // A copy points at an earlier vertex that went to a bucket, now resolved.
    for v in 0..vertices as usize {
        if copies[v / 64] & (1 << (v % 64)) != 0 {
            representative[v] = representative[representative[v] as usize];
        }
    }
    Ok(representative)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{MeshSoup, SPILL_ROWS, Weld, weld};

    /// `soup` spilled as one input file.
    fn spilled(soup: MeshSoup, folder: &Path) -> SoupFiles {
        let mut soup = soup;
        soup.spill.0 = Some(Box::new(
            SoupFiles::create(folder).unwrap().for_file(SPILL_ROWS),
        ));
        soup.spill_now();
        let spill = soup.spill.0.take().unwrap();
        spill.finish(soup).unwrap()
    }

    /// A soup with repeated positions (`-0.0` among them), triangles that welding makes
    /// degenerate and vertices no triangle uses.
    fn soup(seed: u64, vertices: u32, triangles: u32) -> MeshSoup {
        let mut state = seed;
        let mut next = |n: u32| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 33) % u64::from(n)) as u32
        };
        let values = [0.0, -0.0, 1.0, 2.5, -3.0, 7.0];
        let used = vertices - vertices / 8;
        // The last eighth, which no triangle uses, at positions of their own.
        let positions: Vec<[f32; 3]> = (0..vertices)
            .map(|v| match v < used {
                true => [0; 3].map(|_| values[next(values.len() as u32) as usize]),
                false => [v as f32, 0.5, 0.5],
            })
            .collect();
        let triangles: Vec<[u32; 3]> = (0..triangles)
            .map(|_| [next(used), next(used), next(used)])
            .collect();
        let triangle_parts = (0..triangles.len() as u32).map(|t| t % 3).collect();
        MeshSoup {
            positions,
            triangles,
            triangle_parts,
            part_names: (0..3).map(|k| format!("part {k}")).collect(),
            parts: vec![PartInfo::default(); 3],
            ..MeshSoup::default()
        }
    }

    #[test]
    fn the_weld_on_disk_makes_the_scene_the_weld_in_memory_makes() {
        let folder = tempfile::tempdir().unwrap();
        for seed in 0..6 {
            let soup = soup(seed, 3_000, 4_000);
            let expected = weld(soup.clone(), Weld::Exact);
            assert!(expected.stats.welded_vertices > 0);
            assert!(expected.stats.degenerate_triangles_dropped > 0);
            assert!(expected.stats.unreferenced_vertices_dropped > 0);
            // One bucket, a few, and more than `MAX_BUCKETS` asked for; positions remembered
            // while scattering, one (nearly every copy to a bucket) and more than there are;
            // representatives written back in one share a bucket, and in many.
            for (bucket_vertices, recent, share) in [
                (1 << 20, 1, WRITE_BACK_SHARE),
                (700, 1, 1),
                (700, 1 << 16, 7),
                (1, 4, WRITE_BACK_SHARE),
            ] {
                let scene = spilled(soup.clone(), folder.path())
                    .weld_in_buckets_of(bucket_vertices, recent, share)
                    .unwrap();
                assert_eq!(scene.triangle_count, expected.triangles.len() as u64);
                assert_eq!(scene.to_scene().unwrap(), expected, "seed {seed}");
            }
        }
    }

    #[test]
    fn triangle_runs_number_the_welded_triangles_in_order() {
        let folder = tempfile::tempdir().unwrap();
        let soup = soup(9, (RUN as u32) / 2, RUN as u32 + 1000);
        let expected = weld(soup.clone(), Weld::Exact);
        let scene = spilled(soup, folder.path()).weld().unwrap();
        let mut runs = Vec::new();
        scene
            .for_each_triangle_run(
                |first, t, p| {
                    assert_eq!(t.len(), p.len());
                    runs.push((first, t.len()));
                    Ok::<(), ImportError>(())
                },
                |e| e,
            )
            .unwrap();
        assert_eq!(runs.len(), 2, "two runs of the file");
        assert_eq!(runs[0].0, 0);
        assert_eq!(runs[1].0, runs[0].1 as u64);
        assert_eq!(
            (runs[0].1 + runs[1].1) as u64,
            expected.triangles.len() as u64
        );
    }
}

#[cfg(test)]
mod file_tests {
    use std::io::Write;
    use std::path::{Path, PathBuf};

    use super::SoupFiles;
    use crate::{ImportOptions, Weld, load_files};

    /// A grid of `n × n` vertices (each written twice, so that welding joins them) and its
    /// triangles; every `quad_every`-th face written as a quad when that is set.
    fn grid(n: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut positions = Vec::new();
        for copy in 0..2 {
            for y in 0..n {
                for x in 0..n {
                    let _ = copy;
                    positions.push([x as f32, y as f32, ((x * y) % 3) as f32 - 1.0]);
                }
            }
        }
        let mut triangles = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x + (x % 2) * n * n; // half the corners from the copy
                triangles.push([v, v + 1, v + n]);
                triangles.push([v + 1, v + n + 1, v + n]);
            }
        }
        // One triangle that welding makes degenerate.
        triangles.push([0, n * n, 1]);
        (positions, triangles)
    }

    fn gzip(bytes: &[u8]) -> Vec<u8> {
        let mut out = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        out.write_all(bytes).unwrap();
        out.finish().unwrap()
    }

    fn write(folder: &Path, name: &str, bytes: &[u8]) -> PathBuf {
        let path = folder.join(name);
        std::fs::File::create(&path)
            .unwrap()
            .write_all(bytes)
            .unwrap();
        path
    }

    /// A binary little-endian PLY with vertex colours or face colours, a face `part`, and
    /// one quad when `quad` (which sends that piece to the general reader).
    fn binary_ply(vertex_colors: bool, quad: bool) -> Vec<u8> {
        let (positions, triangles) = grid(9);
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
            positions.len()
        );
        if vertex_colors {
            header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
        }
        header += &format!(
            "element face {}\nproperty list uchar uint vertex_indices\nproperty uint part\n",
            triangles.len() + usize::from(quad)
        );
        if !vertex_colors {
            header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
        }
        header += "end_header\n";
        let mut out = header.into_bytes();
        for (i, p) in positions.iter().enumerate() {
            for c in p {
                out.extend_from_slice(&c.to_le_bytes());
            }
            if vertex_colors {
                out.extend_from_slice(&[(i * 7) as u8, (i * 13) as u8, 200]);
            }
        }
        let mut faces: Vec<Vec<u32>> = triangles.iter().map(|t| t.to_vec()).collect();
        if quad {
            faces.insert(20, vec![0, 1, 10, 9]);
        }
        for (i, f) in faces.iter().enumerate() {
            out.push(f.len() as u8);
            for v in f {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&((i / 30) as u32 * 5).to_le_bytes());
            if !vertex_colors {
                out.extend_from_slice(&[(i * 3) as u8, 10, (i * 11) as u8]);
            }
        }
        out
    }

    fn ascii_ply() -> Vec<u8> {
        let (positions, triangles) = grid(6);
        let mut out = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
            positions.len(),
            triangles.len()
        );
        for p in &positions {
            out += &format!("{} {} {}\n", p[0], p[1], p[2]);
        }
        for t in &triangles {
            out += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
        }
        out.into_bytes()
    }

    fn binary_stl() -> Vec<u8> {
        let (positions, triangles) = grid(7);
        let mut out = vec![0u8; 80];
        out.extend_from_slice(&(triangles.len() as u32).to_le_bytes());
        for t in &triangles {
            out.extend_from_slice(&[0u8; 12]);
            for &v in t {
                for c in positions[v as usize] {
                    out.extend_from_slice(&(c + 20.0).to_le_bytes());
                }
            }
            out.extend_from_slice(&[0, 0]);
        }
        out
    }

    /// An ASCII STL file of two solids (the second unnamed), lines ending in `ending`.
    fn ascii_stl(ending: &str) -> Vec<u8> {
        let (positions, triangles) = grid(9);
        let mut out = format!("solid first{ending}");
        let half = triangles.len() / 2;
        for (k, t) in triangles.iter().enumerate() {
            if k == half {
                out += &format!("endsolid first{ending}solid{ending}");
            }
            out += &format!("  facet normal 0 0 1{ending}    outer loop{ending}");
            for &v in t {
                let p = positions[v as usize];
                out += &format!("      vertex {} {} {}{ending}", p[0], p[1] + 40.0, p[2]);
            }
            out += &format!("    endloop{ending}  endfacet{ending}");
        }
        out += &format!("endsolid{ending}");
        out.into_bytes()
    }

    const OBJ: &[u8] =
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\ng left\nf 1 2 3\ng right\nf 2 4 3\nf 1 1 2\n";

    /// An OBJ file of more than one piece of text (over a megabyte), in two groups, with
    /// relative indices in the second, lines ending in `ending`.
    fn large_obj(ending: &str) -> Vec<u8> {
        let (positions, triangles) = grid(220);
        let mut out = String::new();
        for p in &positions {
            out += &format!("v {} {} {}{ending}", p[0], p[1], p[2] * 0.25);
        }
        let half = triangles.len() / 2;
        out += &format!("g first{ending}");
        for t in &triangles[..half] {
            out += &format!("f {} {} {}{ending}", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        out += &format!("g second{ending}");
        let n = positions.len() as i64;
        for t in &triangles[half..] {
            let r = t.map(|v| i64::from(v) - n);
            out += &format!("f {} {} {}{ending}", r[0], r[1], r[2]);
        }
        assert!(out.len() > 2 * crate::obj::CHUNK_BYTES);
        out.into_bytes()
    }

    #[test]
    fn spilled_import_reads_every_format_as_the_import_in_memory_does() {
        let folder = tempfile::tempdir().unwrap();
        let f = folder.path();
        let paths = vec![
            write(f, "a.ply", &binary_ply(true, false)),
            write(f, "b.ply", &binary_ply(false, true)),
            write(f, "c.ply", &ascii_ply()),
            write(f, "d.stl", &binary_stl()),
            write(f, "e.obj", OBJ),
            write(f, "f.obj", &large_obj("\n")),
            write(f, "g.obj", &large_obj("\r")),
            write(f, "h.ply.gz", &gzip(&binary_ply(true, false))),
            write(f, "i.stl", &ascii_stl("\n")),
            write(f, "j.stl", &ascii_stl("\r\n")),
            write(f, "k.ply", &signed_ply_without_parts()),
        ];
        let options = ImportOptions {
            weld: Weld::Exact,
            ..ImportOptions::default()
        };
        let expected = load_files(&paths, &options).unwrap();
        assert!(expected.parts.iter().any(|p| p.color.is_some()));
        // Pieces of a few rows, of more rows than any file has, and of one row.
        for rows in [7, 1 << 20, 1] {
            let scene = crate::spill_files_in_pieces(&paths, &options, f, rows).unwrap();
            assert_eq!(scene.to_scene().unwrap(), expected, "pieces of {rows} rows");
        }
    }

    #[test]
    fn an_ascii_stl_is_read_a_piece_at_a_time() {
        let folder = tempfile::tempdir().unwrap();
        let bytes = ascii_stl("\n");
        let mut soup = crate::MeshSoup::default();
        let files = super::SoupFiles::create(folder.path()).unwrap();
        soup.spill.0 = Some(Box::new(files.for_file(7)));
        crate::stl::read_stl(&bytes, "x", &mut soup).unwrap();
        // All but the last piece's facets were spilled as the file was read.
        let (_, spilled) = soup.spill.0.as_ref().unwrap().spilled();
        assert_eq!(spilled + soup.triangles.len(), grid(9).1.len());
        assert!(soup.triangles.len() < 7, "{} held", soup.triangles.len());
        assert_eq!(soup.parts.len(), 2);
    }

    #[test]
    fn a_bad_row_in_a_later_piece_is_named_as_in_memory() {
        let folder = tempfile::tempdir().unwrap();
        let mut bytes = binary_ply(false, false);
        // Corrupt the last face's first corner (its count byte, three `u32` corners, a part
        // and three colour bytes end the file).
        let at = bytes.len() - (3 + 4 + 12);
        bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        let path = write(folder.path(), "bad.ply", &bytes);
        let options = ImportOptions::default();
        let in_memory = load_files(&[&path], &options).unwrap_err().to_string();
        let spilled = crate::spill_files_in_pieces(&[&path], &options, folder.path(), 7)
            .unwrap_err()
            .to_string();
        assert_eq!(spilled, in_memory);
        assert!(in_memory.contains("face"), "{in_memory}");
    }

    /// A binary PLY whose faces have `int` indices and no part.
    fn signed_ply_without_parts() -> Vec<u8> {
        let (positions, triangles) = grid(5);
        let mut out = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
             property float y\nproperty float z\nelement face {}\n\
             property list uchar int vertex_indices\nend_header\n",
            positions.len(),
            triangles.len()
        )
        .into_bytes();
        for p in &positions {
            out.extend(p.iter().flat_map(|c| c.to_le_bytes()));
        }
        for t in &triangles {
            out.push(3);
            out.extend(t.iter().flat_map(|&v| (v as i32).to_le_bytes()));
        }
        out
    }

    /// `paths` read into spill files in pieces of `rows` rows, not yet welded.
    fn read_spilled(paths: &[PathBuf], folder: &Path, rows: usize) -> SoupFiles {
        let mut files = SoupFiles::create(folder).unwrap();
        let options = ImportOptions::default();
        for path in paths {
            let mut soup = crate::MeshSoup::default();
            soup.spill.0 = Some(Box::new(files.for_file(rows)));
            crate::read_into(path, &options, u64::MAX, &mut soup).unwrap();
            soup.spill_now();
            let spill = soup.spill.0.take().unwrap();
            files = spill.finish(soup).unwrap();
        }
        files
    }

    #[test]
    fn binary_ply_rows_are_read_again_from_the_map_not_spilled() {
        let folder = tempfile::tempdir().unwrap();
        let f = folder.path();
        let paths = [
            write(f, "a.ply", &binary_ply(true, false)),
            write(f, "k.ply", &signed_ply_without_parts()),
            write(f, "d.stl", &binary_stl()),
        ];
        let files = read_spilled(&paths, f, 7);
        // Nothing spilled, and the pieces of each file's rows joined into one run per file.
        assert_eq!(
            (files.position_runs.spilled, files.triangle_runs.spilled),
            (0, 0)
        );
        assert_eq!(files.position_runs.list.len(), 3);
        assert_eq!(files.triangle_runs.list.len(), 3);
        let options = ImportOptions {
            weld: Weld::Exact,
            ..ImportOptions::default()
        };
        let expected = load_files(&paths, &options).unwrap();
        assert_eq!(files.weld().unwrap().to_scene().unwrap(), expected);

        // A piece with a quad is spilled; the pieces around it are still mapped.
        let quad = [write(f, "b.ply", &binary_ply(false, true))];
        let files = read_spilled(&quad, f, 7);
        assert_eq!(
            files.triangle_runs.spilled, 8,
            "the quad's piece: 6 triangles and 2"
        );
        assert_eq!(files.triangle_runs.list.len(), 3);
    }

    #[test]
    fn a_file_changed_after_it_was_read_is_an_error_naming_it() {
        let folder = tempfile::tempdir().unwrap();
        for (name, bytes) in [
            ("changed.ply", binary_ply(false, false)),
            ("changed.stl", binary_stl()),
        ] {
            let path = write(folder.path(), name, &bytes);
            let files = read_spilled(std::slice::from_ref(&path), folder.path(), 7);
            // The same length, and every row still valid: a corner of the last face moved
            // to vertex 0 (PLY), a facet's corner nudged (STL).
            let mut changed = bytes.clone();
            let at = changed.len() - 50 + 12;
            changed[at..at + 4].copy_from_slice(&0u32.to_le_bytes());
            // Past the file system's clock tick (a few milliseconds on some), so that the
            // write's time of change differs from the first one's.
            std::thread::sleep(std::time::Duration::from_millis(20));
            std::fs::write(&path, &changed).unwrap();
            let message = files.weld().unwrap_err().to_string();
            assert!(message.contains(name), "{message}");
            assert!(message.contains("changed"), "{message}");
        }
    }

    #[test]
    fn rows_changed_unnoticed_are_errors_naming_the_row() {
        let folder = tempfile::tempdir().unwrap();
        let bytes = binary_ply(false, false);
        let path = write(folder.path(), "changing.ply", &bytes);
        // The 101st face's first corner (count byte, three corners, part, three colours).
        let face = 101u64;
        let faces = grid(9).1.len();
        let at = bytes.len() - (faces - face as usize) * (1 + 12 + 4 + 3) + 1;
        let cases = [
            (at, 9_999u32, "out of range"),
            (at, u32::MAX, "out of range"),
            (at + 12, 77_777, "part 77777"),
        ];
        for (at, value, problem) in cases {
            let mut files = read_spilled(std::slice::from_ref(&path), folder.path(), 7);
            files.forget_identities();
            let mut changed = bytes.clone();
            changed[at..at + 4].copy_from_slice(&value.to_le_bytes());
            std::fs::write(&path, &changed).unwrap();
            let message = files.weld().unwrap_err().to_string();
            assert!(message.contains("changing.ply"), "{message}");
            assert!(message.contains(&format!("face {face}")), "{message}");
            assert!(message.contains(problem), "{message}");
            std::fs::write(&path, &bytes).unwrap();
        }
        // A facet's corner that is no longer a number.
        let stl = binary_stl();
        let path = write(folder.path(), "changing.stl", &stl);
        let mut files = read_spilled(std::slice::from_ref(&path), folder.path(), 7);
        files.forget_identities();
        // Facet 40's second corner's y (80-byte header, 4-byte count, 50-byte facets).
        let at = 84 + 40 * 50 + 24 + 4;
        let mut changed = stl.clone();
        changed[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        std::fs::write(&path, &changed).unwrap();
        let message = files.weld().unwrap_err().to_string();
        assert!(message.contains("changing.stl"), "{message}");
        assert!(message.contains("triangle 40"), "{message}");
    }

    #[test]
    fn an_input_truncated_after_it_was_read_is_an_error_naming_it() {
        let folder = tempfile::tempdir().unwrap();
        for (name, bytes) in [
            ("cut.ply", binary_ply(false, false)),
            ("cut.stl", binary_stl()),
        ] {
            let path = write(folder.path(), name, &bytes);
            let files = read_spilled(std::slice::from_ref(&path), folder.path(), 7);
            std::fs::OpenOptions::new()
                .write(true)
                .open(&path)
                .unwrap()
                .set_len(bytes.len() as u64 / 2)
                .unwrap();
            let message = files.weld().unwrap_err().to_string();
            assert!(message.contains(name), "{message}");
        }
    }
}
