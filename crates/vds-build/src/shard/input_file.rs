//! A shard's input (`.vdtin`): what [`ShardInput`] holds, in the sharded build's container
//! ([`super::container`]). The body is three runs of records:
//!
//! 1. the shard's own vertices (those under its roots; as many as its roots' leaves), as
//!    [`InputVertex`] records (16 bytes: id, position), in id order;
//! 2. every triangle with a corner in the shard, as [`InputTriangle`] records (24 bytes:
//!    index, part, corners' ids), in scene order (as many as the plan's count for the shard);
//! 3. the vertices of those triangles' corners under other shards' roots, as [`InputVertex`]
//!    records in id order, each once (the rest of the body).
//!
//! A vertex is stored once, not with each triangle that uses it: about 33 bytes a triangle
//! instead of the 60 of a triangle with its corners' positions. `vds-build plan` writes every
//! shard's input in passes over the scene (the own vertices first, in a pass over the
//! vertices); a shard reads only its own.
//!
//! Each run is stored in *shuffled blocks*: its records [`BLOCK_RECORDS`] at a time from the
//! start of the run (the last block of a run may hold fewer), each block as its records'
//! first bytes, then their second bytes, and so on (a byte-plane transposition, as Blosc's and
//! HDF5's shuffle filters do). Ids and positions of neighbouring records share their high
//! bytes, so the planes hold long repeats, which the body's LZ4 frame finds: the generated
//! 20 M scene's shard inputs take 1.4 bytes a triangle where the records as they are took 15,
//! and the scanned dragon's 10 where they took 20. Compressing and writing them were the
//! plan's largest costs after the weld. A reader knows each run's record count (the plan's
//! counts and the body's length), so the blocks need no markers.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use zerocopy::{FromZeros, IntoBytes};

use super::container::{BodyReader, BodyWriter, Codec, Durability, body_stream, read_ends};
use super::part::{InputTriangle, InputVertex, ShardInput, input_triangle, input_vertex};
use super::{Plan, PlanScene, ShardError};

/// The first eight bytes of a `.vdtin` file.
pub const INPUT_MAGIC: [u8; 8] = *b"VDTINPUT";
/// What errors call the file.
const WHAT: &str = "shard input file";
const TRIANGLE_BYTES: u64 = size_of::<InputTriangle>() as u64;
const VERTEX_BYTES: u64 = size_of::<InputVertex>() as u64;
/// Bytes a shard input file holds while it is written: an open file, an LZ4 encoder (about
/// 150 KB), two shuffled blocks (192 KiB) and its share of a run of records (a `vds-build
/// plan` of the 10 M scene peaked 2.8 MB higher per file from 1 to 96 shards, the plan's own
/// records per root included, before blocks were shuffled), besides the ids of its corners in
/// other shards, 4 bytes each once per run, held until the end of the pass (about 3 % of its
/// triangles' on the generated scenes).
pub const INPUT_WRITER_BYTES: u64 = (3 << 20) + (256 << 10);
/// The most files written by one pass over the scene: many shards take several passes.
pub const MAX_FILES_PER_PASS: usize = 128;
/// Triangles or vertices gathered before the files compress them.
const RECORDS_PER_RUN: usize = 1 << 16;
/// Records per shuffled block (see the module documentation): 64 or 96 KiB of vertices or
/// triangles, held twice by each file being written. Blocks of 16 K records made one of the
/// 20 M scene's shard inputs a third smaller (shuffled by a script, then `lz4 -1`, whose
/// blocks are larger than the frame's here), for four times the memory per file.
const BLOCK_RECORDS: usize = 4096;
/// Bytes of a block of the largest records, which each writer's buffers are made to hold.
const BLOCK_BYTES: usize = BLOCK_RECORDS * TRIANGLE_BYTES as usize;

/// How many of `scene`'s triangles each shard of `plan` reads: those with a corner under
/// one of its roots (`root_of`, from [`super::roots_of_vertices`]). A pass over the scene of
/// its own; [`write_shard_inputs`] counts them as it writes them (this is its reference).
pub fn shard_triangle_counts(
    scene: &impl PlanScene,
    plan: &Plan,
    root_of: &[u32],
) -> Result<Vec<u64>, ShardError> {
    let shard_of_root = shard_of_root(plan);
    let mut counts = vec![0u64; plan.shard_count() as usize];
    scene.for_each_triangle_run(&mut |_, triangles, _| {
        for t in triangles {
            for_each_shard(corner_shards(t, root_of, &shard_of_root), |k| {
                counts[k] += 1
            });
        }
        Ok(())
    })?;
    Ok(counts)
}

fn shard_of_root(plan: &Plan) -> Vec<u32> {
    (0..plan.shard_count())
        .flat_map(|k| plan.shard_roots(k).map(move |_| k))
        .collect()
}

/// The shard of each of a triangle's corners.
fn corner_shards(t: &[u32; 3], root_of: &[u32], shard_of_root: &[u32]) -> [usize; 3] {
    t.map(|v| shard_of_root[root_of[v as usize] as usize] as usize)
}

/// Calls `f` once for each shard a triangle's corners lie in (`shards`, from
/// [`corner_shards`]).
fn for_each_shard(shards: [usize; 3], mut f: impl FnMut(usize)) {
    let mut sorted = shards;
    sorted.sort_unstable();
    for (k, &shard) in sorted.iter().enumerate() {
        if k == 0 || sorted[k - 1] != shard {
            f(shard);
        }
    }
}

/// Writes every shard's input file (`paths[k]` for shard `k`) from `scene`, each written
/// beside its target and renamed into place when complete, at most `files_per_pass` (1 to
/// [`MAX_FILES_PER_PASS`]; each holds about [`INPUT_WRITER_BYTES`]) in one pass over the
/// scene's vertices and then its triangles. `on_progress(done, total)` is told how many
/// triangles the passes over the scene have gone through.
///
/// Returns how many triangles each shard's input holds (what [`shard_triangle_counts`]
/// counts), which a plan records before its id is taken: the files name `plan` as it is
/// when they are written, and [`stamp_shard_inputs`] names the plan that records the counts.
/// `durability`: whether each file is synced before it is renamed into place.
#[allow(clippy::too_many_arguments)]
pub fn write_shard_inputs(
    scene: &impl PlanScene,
    plan: &Plan,
    root_of: &[u32],
    paths: &[PathBuf],
    files_per_pass: usize,
    durability: Durability,
    mut on_progress: impl FnMut(u64, u64),
) -> Result<Vec<u64>, ShardError> {
    let files_per_pass = files_per_pass.clamp(1, MAX_FILES_PER_PASS);
    let mut counts = vec![0u64; paths.len()];
    let shard_of_root = shard_of_root(plan);
    let passes = paths.len().div_ceil(files_per_pass) as u64;
    let total = passes * scene.triangle_count();
    let positions = scene.positions();
    let mut done = 0u64;
    // Runs are gathered per file, a piece of the run on each thread, then each file
    // compresses its share on its own task (the files are independent streams, each still
    // written in order: its pieces one after the other).
    let pieces = rayon::current_num_threads().max(1);
    for first in (0..paths.len()).step_by(files_per_pass) {
        let batch = first..(first + files_per_pass).min(paths.len());
        let mut files = batch
            .clone()
            .map(|k| InputWriter::create(&paths[k], k as u32, plan.id, durability))
            .collect::<Result<Vec<_>, _>>()?;
        let mut gathered = Gathered::new(pieces, batch.len());
        // The shards' own vertices, in id order.
        for run_first in (0..positions.len()).step_by(RECORDS_PER_RUN) {
            let run = run_first..(run_first + RECORDS_PER_RUN).min(positions.len());
            gathered.gather(run.len(), |i, out| {
                let v = (run.start + i) as u32;
                let k = shard_of_root[root_of[v as usize] as usize] as usize;
                if batch.contains(&k) {
                    let record = input_vertex(v, positions);
                    out.bytes[k - first].extend_from_slice(record.as_bytes());
                }
            });
            gathered.put(&mut files)?;
        }
        files
            .par_iter_mut()
            .try_for_each(|file| file.next_run(TRIANGLE_BYTES as usize).map(drop))?;
        // The triangles, noting their corners in other shards.
        let mut elsewhere: Vec<Vec<u32>> = vec![Vec::new(); batch.len()];
        scene.for_each_triangle_run(&mut |run_first, triangles, parts| {
            for (sub, (triangles, parts)) in triangles
                .chunks(RECORDS_PER_RUN)
                .zip(parts.chunks(RECORDS_PER_RUN))
                .enumerate()
            {
                let sub_first = run_first + (sub * RECORDS_PER_RUN) as u64;
                // Triangles with a part each (as the zip of the two would take them).
                let n = triangles.len().min(parts.len());
                gathered.gather(n, |i, out| {
                    let t = triangles[i];
                    let shards = corner_shards(&t, root_of, &shard_of_root);
                    for_each_shard(shards, |k| {
                        if batch.contains(&k) {
                            let record = input_triangle(sub_first + i as u64, parts[i], t);
                            out.bytes[k - first].extend_from_slice(record.as_bytes());
                            for (&v, &shard) in t.iter().zip(&shards) {
                                if shard != k {
                                    out.elsewhere[k - first].push(v);
                                }
                            }
                        }
                    });
                });
                gathered.put(&mut files)?;
                gathered.take_elsewhere(&mut elsewhere);
                done += n as u64;
                on_progress(done, total);
            }
            Ok(())
        })?;
        // The corners in other shards, in id order, once each.
        files
            .par_iter_mut()
            .zip(&mut elsewhere)
            .zip(&mut counts[batch.clone()])
            .try_for_each(|((file, ids), count)| {
                *count = file.next_run(VERTEX_BYTES as usize)?;
                ids.sort_unstable();
                ids.dedup();
                let mut records = Vec::with_capacity(RECORDS_PER_RUN * VERTEX_BYTES as usize);
                for run in ids.chunks(RECORDS_PER_RUN) {
                    records.clear();
                    for &v in run {
                        records.extend_from_slice(input_vertex(v, positions).as_bytes());
                    }
                    file.put(&records)?;
                }
                Ok::<(), ShardError>(())
            })?;
        drop(elsewhere);
        for file in files {
            file.finish()?;
        }
    }
    Ok(counts)
}

/// Names `plan` (sealed, with its shards' triangle counts) in the header of each shard's input
/// that [`write_shard_inputs`] wrote to `paths` for it when its id was `written_for`, before
/// the counts; each header is synced where `durability` says.
pub fn stamp_shard_inputs(
    paths: &[PathBuf],
    written_for: u64,
    plan: &Plan,
    durability: Durability,
) -> Result<(), ShardError> {
    for (k, path) in paths.iter().enumerate() {
        let file = (k as u32, written_for);
        super::container::restamp(path, INPUT_MAGIC, WHAT, file, plan.id, durability)?;
    }
    Ok(())
}

/// A shard input being written: its runs of records, each stored in shuffled blocks (see
/// the module documentation).
struct InputWriter {
    body: BodyWriter,
    /// Bytes of one record of the run being written.
    record_bytes: usize,
    /// Records of the run being written so far.
    records: u64,
    /// Records of the run's current block.
    block: Vec<u8>,
    /// The block shuffled.
    planes: Vec<u8>,
}

impl InputWriter {
    /// Starts the input of shard `index` of plan `plan_id` at `path`, with its own vertices.
    fn create(
        path: &Path,
        index: u32,
        plan_id: u64,
        durability: Durability,
    ) -> Result<InputWriter, ShardError> {
        Ok(InputWriter {
            body: BodyWriter::create(path, INPUT_MAGIC, index, plan_id, durability)?,
            record_bytes: VERTEX_BYTES as usize,
            records: 0,
            block: Vec::with_capacity(BLOCK_BYTES),
            planes: Vec::with_capacity(BLOCK_BYTES),
        })
    }

    /// Appends whole records to the run being written.
    fn put(&mut self, mut records: &[u8]) -> Result<(), ShardError> {
        debug_assert_eq!(records.len() % self.record_bytes, 0, "whole records");
        self.records += (records.len() / self.record_bytes) as u64;
        let full = BLOCK_RECORDS * self.record_bytes;
        while !records.is_empty() {
            let take = (full - self.block.len()).min(records.len());
            self.block.extend_from_slice(&records[..take]);
            records = &records[take..];
            if self.block.len() == full {
                self.write_block()?;
            }
        }
        Ok(())
    }

    /// Ends the run being written, with its last block, and returns its record count; the
    /// next holds records of `record_bytes`.
    fn next_run(&mut self, record_bytes: usize) -> Result<u64, ShardError> {
        self.end_block()?;
        self.record_bytes = record_bytes;
        Ok(std::mem::take(&mut self.records))
    }

    /// Writes the block gathered so far, if any, shuffled.
    fn end_block(&mut self) -> Result<(), ShardError> {
        if self.block.is_empty() {
            return Ok(());
        }
        self.write_block()
    }

    fn write_block(&mut self) -> Result<(), ShardError> {
        shuffle(&self.block, self.record_bytes, &mut self.planes);
        self.block.clear();
        self.body.put(&self.planes)
    }

    /// Ends the last run and the file.
    fn finish(mut self) -> Result<(), ShardError> {
        self.end_block()?;
        self.body.finish()
    }
}

/// `records`, whole records of `record_bytes` each, as byte planes into `planes`: every
/// record's first byte, then every record's second byte, and so on.
fn shuffle(records: &[u8], record_bytes: usize, planes: &mut Vec<u8>) {
    debug_assert_eq!(records.len() % record_bytes, 0, "whole records");
    let count = records.len() / record_bytes;
    planes.clear();
    planes.resize(records.len(), 0);
    for (b, plane) in planes.chunks_exact_mut(count.max(1)).enumerate() {
        for (byte, record) in plane.iter_mut().zip(records.chunks_exact(record_bytes)) {
            *byte = record[b];
        }
    }
}

/// Undoes [`shuffle`]: `planes` of whole records of `record_bytes` each into `records`.
fn unshuffle(planes: &[u8], record_bytes: usize, records: &mut [u8]) {
    debug_assert_eq!(planes.len(), records.len());
    debug_assert_eq!(planes.len() % record_bytes, 0, "whole records");
    let count = planes.len() / record_bytes;
    for (b, plane) in planes.chunks_exact(count.max(1)).enumerate() {
        for (&byte, record) in plane.iter().zip(records.chunks_exact_mut(record_bytes)) {
            record[b] = byte;
        }
    }
}

/// Undoes the shuffle of a run's blocks in place: `run` holds whole records of
/// `record_bytes` each, as read (`scratch` holds a block at a time).
fn unshuffle_run(run: &mut [u8], record_bytes: usize, scratch: &mut Vec<u8>) {
    for block in run.chunks_mut(BLOCK_RECORDS * record_bytes) {
        scratch.clear();
        scratch.extend_from_slice(block);
        unshuffle(scratch, record_bytes, block);
    }
}

/// One piece of a run: records gathered for each file of a pass, and each file's corners in
/// other shards.
#[derive(Clone, Default)]
struct Piece {
    bytes: Vec<Vec<u8>>,
    elsewhere: Vec<Vec<u32>>,
}

/// A run of records gathered a piece per thread.
struct Gathered {
    pieces: Vec<Piece>,
}

impl Gathered {
    fn new(pieces: usize, files: usize) -> Gathered {
        let piece = Piece {
            bytes: vec![Vec::new(); files],
            elsewhere: vec![Vec::new(); files],
        };
        Gathered {
            pieces: vec![piece; pieces],
        }
    }

    /// Calls `each(i, piece)` for `i` in `0..n`, the range cut into one contiguous share per
    /// piece, the shares side by side.
    fn gather(&mut self, n: usize, each: impl Fn(usize, &mut Piece) + Sync) {
        let share = n.div_ceil(self.pieces.len());
        self.pieces
            .par_iter_mut()
            .enumerate()
            .for_each(|(p, piece)| {
                let start = (p * share).min(n);
                let end = (start + share).min(n);
                for i in start..end {
                    each(i, piece);
                }
            });
    }

    /// Appends what was gathered to the files, pieces in order, and empties the pieces.
    fn put(&mut self, files: &mut [InputWriter]) -> Result<(), ShardError> {
        let pieces = &self.pieces;
        files.par_iter_mut().enumerate().try_for_each(|(j, file)| {
            for piece in pieces {
                file.put(&piece.bytes[j])?;
            }
            Ok::<(), ShardError>(())
        })?;
        for piece in &mut self.pieces {
            piece.bytes.iter_mut().for_each(Vec::clear);
        }
        Ok(())
    }

    /// Moves the corners in other shards that were gathered to `elsewhere`, file by file,
    /// each id once per run (a corner is shared by several triangles of a run).
    fn take_elsewhere(&mut self, elsewhere: &mut [Vec<u32>]) {
        self.pieces.par_iter_mut().for_each(|piece| {
            for ids in &mut piece.elsewhere {
                ids.sort_unstable();
                ids.dedup();
            }
        });
        for piece in &mut self.pieces {
            for (all, ids) in elsewhere.iter_mut().zip(&mut piece.elsewhere) {
                all.append(ids);
            }
        }
    }
}

/// Reads shard `index`'s input file, which must be for `plan`.
pub fn read_shard_input(path: &Path, plan: &Plan, index: u32) -> Result<ShardInput, ShardError> {
    plan.check_index(index)?;
    let bad = |reason: String| ShardError::BadFile {
        path: path.to_path_buf(),
        reason,
    };
    let (header, trailer) = read_ends(path, INPUT_MAGIC, WHAT)?;
    if header.plan_id != plan.id || header.index != index {
        return Err(bad(format!(
            "the input of shard {} of plan {:016x}, not of shard {index} of this plan ({:016x})",
            header.index, header.plan_id, plan.id
        )));
    }
    let Some(&triangles) = plan.shard_triangles.get(index as usize) else {
        return Err(bad(
            "the plan does not say how many triangles its shards read".into(),
        ));
    };
    let own: u64 = plan
        .shard_roots(index)
        .map(|r| {
            let node = plan.root_node(r);
            u64::from(node.leaf_end - node.leaf_begin)
        })
        .sum();
    // The counts come from the plan, a file, and the rest from the body's stated length: both
    // are bounded before anything is allocated (a triangle has a corner in the shard, so at
    // most two elsewhere, and those are among the plan's other vertices), and a plan stating
    // more than memory holds gets an error, not an abort.
    let fixed = own * VERTEX_BYTES + triangles * TRIANGLE_BYTES;
    let most_elsewhere = (2 * triangles).min(u64::from(plan.vertices).saturating_sub(own));
    let rest = trailer.body_bytes.checked_sub(fixed);
    let Some(elsewhere) = rest
        .filter(|r| r % VERTEX_BYTES == 0 && r / VERTEX_BYTES <= most_elsewhere)
        .map(|r| r / VERTEX_BYTES)
    else {
        return Err(bad(format!(
            "{} bytes of records; the plan gives this shard {own} vertices and {triangles} \
             triangles",
            trailer.body_bytes
        )));
    };
    let too_many = || bad("the shard's records do not fit in memory".into());
    let mut vertices = zeroed::<InputVertex>(own + elsewhere).ok_or_else(too_many)?;
    let mut input_triangles = zeroed::<InputTriangle>(triangles).ok_or_else(too_many)?;
    let (own_vertices, other_vertices) = vertices.split_at_mut(own as usize);
    let mut body = BodyReader::new(body_stream(path)?, Codec::of(INPUT_MAGIC), &trailer);
    let mut scratch = Vec::new();
    for (run, record_bytes) in [
        (own_vertices.as_mut_bytes(), VERTEX_BYTES),
        (input_triangles.as_mut_bytes(), TRIANGLE_BYTES),
        (other_vertices.as_mut_bytes(), VERTEX_BYTES),
    ] {
        body.read_exact(run).map_err(bad)?;
        unshuffle_run(run, record_bytes as usize, &mut scratch);
    }
    body.finish().map_err(bad)?;
    if !in_one_order(&mut vertices, own as usize) {
        return Err(bad("vertices out of order, or listed twice".into()));
    }
    Ok(ShardInput {
        triangles: input_triangles,
        vertices,
    })
}

/// `count` zeroed records, or `None` where memory does not hold them.
fn zeroed<T: FromZeros + Clone>(count: u64) -> Option<Vec<T>> {
    let count = usize::try_from(count).ok()?;
    let mut records = Vec::new();
    records.try_reserve_exact(count).ok()?;
    records.resize(count, T::new_zeroed());
    Some(records)
}

/// Puts `vertices` (the shard's first `own`, then the others, each run in increasing id
/// order) in id order; false when a run is out of order or an id is in both.
fn in_one_order(vertices: &mut [InputVertex], own: usize) -> bool {
    let increasing = |run: &[InputVertex]| {
        run.windows(2)
            .all(|w| w[0].vertex.get() < w[1].vertex.get())
    };
    let (mine, others) = vertices.split_at(own);
    if !increasing(mine) || !increasing(others) {
        return false;
    }
    // Two sorted runs: the stable sort finds them and merges them once.
    vertices.sort_by_key(|v| v.vertex.get());
    increasing(vertices)
}

#[cfg(test)]
mod tests {
    use super::super::container::encoded;
    use super::*;
    use vds_import::Scene;
    use zerocopy::little_endian::{F32, U32};

    /// A plan of two shards of a bumpy grid, with the shards' triangle counts, and the grid.
    fn planned() -> (Plan, Scene) {
        let mut scene = super::super::bumpy_grid(20);
        let grid = crate::snap_to_grid(&mut scene);
        let metadata = super::super::PlanMetadata {
            page_bytes: 256,
            ..Default::default()
        };
        let triangles = scene.triangles.len() as u64;
        let mut plan = super::super::plan(&scene.positions, triangles, grid, 2, metadata).unwrap();
        let root_of = super::super::roots_of_vertices(&scene, &plan).unwrap();
        plan.shard_triangles = shard_triangle_counts(&scene, &plan, &root_of).unwrap();
        plan.seal();
        (plan, scene)
    }

    /// Shard 0's input as a file body: own vertices, triangles, vertices elsewhere.
    fn body(plan: &Plan, input: &ShardInput) -> (Vec<u8>, usize) {
        let root_of: Vec<u32> = input
            .vertices
            .iter()
            .map(|v| plan.locate(v.position.map(|c| c.get())).unwrap())
            .collect();
        let mine = plan.shard_roots(0);
        let (own, elsewhere): (Vec<_>, Vec<_>) = input
            .vertices
            .iter()
            .zip(&root_of)
            .partition(|(_, r)| mine.contains(r));
        let mut bytes = Vec::new();
        for (v, _) in &own {
            bytes.extend_from_slice(v.as_bytes());
        }
        bytes.extend_from_slice(input.triangles.as_bytes());
        for (v, _) in &elsewhere {
            bytes.extend_from_slice(v.as_bytes());
        }
        (bytes, own.len())
    }

    /// Bodies of the right length but wrong contents, and of wrong lengths, each behind a
    /// valid checksum: every one is refused with an error naming the file, none panics.
    #[test]
    fn crafted_inputs_are_refused() {
        let (plan, scene) = planned();
        let root_of = super::super::roots_of_vertices(&scene, &plan).unwrap();
        let input = super::super::shard_input_of(&scene, &plan, &root_of, 0);
        let (good, own) = body(&plan, &input);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.vdtin");
        let vertex = VERTEX_BYTES as usize;
        let tail = good.len() - (input.vertices.len() - own) * vertex;
        // Stored with each run in shuffled blocks, as the plan writes it.
        let runs = [0..own * vertex, own * vertex..tail, tail..good.len()];
        let stored = |bytes: &[u8]| {
            let mut out = Vec::new();
            for (run, record_bytes) in runs
                .iter()
                .zip([VERTEX_BYTES, TRIANGLE_BYTES, VERTEX_BYTES])
            {
                out.extend(shuffled_run(&bytes[run.clone()], record_bytes as usize));
            }
            out
        };
        let read = |bytes: &[u8]| {
            std::fs::write(&path, encoded(INPUT_MAGIC, 0, plan.id, bytes)).unwrap();
            read_shard_input(&path, &plan, 0)
        };
        let good_stored = stored(&good);
        assert_eq!(read(&good_stored).unwrap(), input);
        let elsewhere = input.vertices.len() - own;
        assert!(elsewhere >= 2, "{elsewhere} vertices elsewhere");
        // Lengths first (the reader checks them before it reads), then contents.
        let mut crafted: Vec<(&str, Vec<u8>)> = Vec::new();
        // Too short for the own vertices and triangles; not a whole vertex past them; more
        // vertices elsewhere than two a triangle.
        crafted.push(("short", good_stored[..tail - 1].to_vec()));
        crafted.push((
            "a partial vertex",
            good_stored[..good_stored.len() - 1].to_vec(),
        ));
        let mut many = good_stored.clone();
        for _ in 0..2 * input.triangles.len() + 1 {
            many.extend_from_slice(&good_stored[good_stored.len() - vertex..]);
        }
        crafted.push(("too many elsewhere", many));
        // Own vertices out of order, an id twice, an id in both runs.
        let mut swapped = good.clone();
        let (first, second) = swapped[..2 * vertex].split_at_mut(vertex);
        first.swap_with_slice(second);
        crafted.push(("own out of order", stored(&swapped)));
        let mut twice = good.clone();
        twice.copy_within(tail..tail + vertex, tail + vertex);
        crafted.push(("an id twice", stored(&twice)));
        let mut both = good.clone();
        both.copy_within(0..vertex, tail);
        crafted.push(("an id in both runs", stored(&both)));
        for (what, bytes) in crafted {
            match read(&bytes) {
                Err(ShardError::BadFile { path: named, .. }) => assert_eq!(named, path, "{what}"),
                other => panic!("{what}: {other:?}"),
            }
        }
    }

    /// Runs written through [`InputWriter`] in pieces that straddle blocks, one longer than a
    /// block and one empty, come back record for record once each run is unshuffled.
    #[test]
    fn a_writer_stores_each_run_in_blocks_from_its_start() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.vdtin");
        let record = |n: usize, bytes: usize, seed: usize| -> Vec<u8> {
            (0..n * bytes)
                .map(|i| (i * 31 + seed + i / 97) as u8)
                .collect()
        };
        let vertex = VERTEX_BYTES as usize;
        let triangle = TRIANGLE_BYTES as usize;
        let runs = [
            (record(BLOCK_RECORDS + 3, vertex, 1), vertex),
            (Vec::new(), triangle),
            (record(2 * BLOCK_RECORDS + 70, vertex, 2), vertex),
        ];
        let mut writer = InputWriter::create(&path, 0, 7, Durability::Transient).unwrap();
        for (k, (bytes, record_bytes)) in runs.iter().enumerate() {
            if k > 0 {
                writer.next_run(*record_bytes).unwrap();
            }
            // Pieces of 1, 1,000 and 3,000 records in turn.
            let mut rest = &bytes[..];
            for pieces in [1usize, 1000, 3000].iter().cycle() {
                if rest.is_empty() {
                    break;
                }
                let (piece, tail) = rest.split_at((pieces * record_bytes).min(rest.len()));
                writer.put(piece).unwrap();
                rest = tail;
            }
        }
        writer.finish().unwrap();
        let (_, trailer) = read_ends(&path, INPUT_MAGIC, WHAT).unwrap();
        let mut body = BodyReader::new(body_stream(&path).unwrap(), Codec::Lz4, &trailer);
        let mut scratch = Vec::new();
        for (bytes, record_bytes) in &runs {
            let mut run = vec![0u8; bytes.len()];
            body.read_exact(&mut run).unwrap();
            assert!(bytes.is_empty() || &run != bytes, "stored shuffled");
            unshuffle_run(&mut run, *record_bytes, &mut scratch);
            assert_eq!(&run, bytes);
        }
        body.finish().unwrap();
    }

    #[test]
    fn shuffled_blocks_come_back_as_written() {
        for record_bytes in [1usize, 16, 24] {
            for count in [
                0usize,
                1,
                7,
                BLOCK_RECORDS - 1,
                BLOCK_RECORDS,
                2 * BLOCK_RECORDS + 5,
            ] {
                let records: Vec<u8> = (0..count * record_bytes)
                    .map(|i| (i * 7 + i / 251) as u8)
                    .collect();
                let stored = shuffled_run(&records, record_bytes);
                assert_eq!(stored.len(), records.len());
                for (block, planes) in records
                    .chunks(BLOCK_RECORDS * record_bytes)
                    .zip(stored.chunks(BLOCK_RECORDS * record_bytes))
                {
                    if block.len() > record_bytes {
                        assert_eq!(planes[1], block[record_bytes], "the first plane");
                    }
                }
                let mut back = stored.clone();
                unshuffle_run(&mut back, record_bytes, &mut Vec::new());
                assert_eq!(back, records, "{count} records of {record_bytes} bytes");
            }
        }
    }

    /// A run of whole records of `record_bytes` each, stored as the writer stores it: in
    /// shuffled blocks from its start.
    fn shuffled_run(records: &[u8], record_bytes: usize) -> Vec<u8> {
        let mut out = Vec::with_capacity(records.len());
        let mut planes = Vec::new();
        for block in records.chunks(BLOCK_RECORDS * record_bytes) {
            shuffle(block, record_bytes, &mut planes);
            out.extend_from_slice(&planes);
        }
        out
    }

    fn vertices(ids: &[u32]) -> Vec<InputVertex> {
        ids.iter()
            .map(|&v| InputVertex {
                vertex: U32::new(v),
                position: [F32::new(v as f32); 3],
            })
            .collect()
    }

    #[test]
    fn runs_merge_in_id_order_and_an_id_in_both_or_out_of_order_is_refused() {
        let ordered = |ids: &[u32], own: usize| {
            let mut run = vertices(ids);
            in_one_order(&mut run, own)
                .then(|| run.iter().map(|v| v.vertex.get()).collect::<Vec<_>>())
        };
        assert_eq!(
            ordered(&[1, 4, 9, 0, 2, 10, 11], 3),
            Some(vec![0, 1, 2, 4, 9, 10, 11])
        );
        assert_eq!(ordered(&[3], 1), Some(vec![3]));
        assert_eq!(ordered(&[3], 0), Some(vec![3]));
        assert_eq!(ordered(&[], 0), Some(vec![]));
        assert_eq!(ordered(&[1, 4, 5], 3), Some(vec![1, 4, 5]));
        assert_eq!(ordered(&[1, 4, 4], 2), None);
        assert_eq!(ordered(&[4, 1, 0], 1), None);
        assert_eq!(ordered(&[1, 1], 2), None);
        assert_eq!(ordered(&[2, 1, 5], 2), None);
        assert_eq!(ordered(&[1, 3, 2, 0], 4), None);
    }
}
