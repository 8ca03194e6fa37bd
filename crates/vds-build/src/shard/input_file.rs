//! A shard's input (`.vdtin`): every triangle with a corner in the shard, in scene order, as
//! [`InputTriangle`] records (60 bytes each), in the sharded build's container
//! ([`super::container`]). `vds-build plan` writes every shard's input in passes over the
//! scene; a shard reads only its own.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use zerocopy::{FromZeros, IntoBytes};

use super::container::{BodyWriter, read_body_into, read_ends};
use super::part::{InputTriangle, input_triangle};
use super::{Plan, PlanScene, ShardError};

/// The first eight bytes of a `.vdtin` file.
pub const INPUT_MAGIC: [u8; 8] = *b"VDTINPUT";
/// What errors call the file.
const WHAT: &str = "shard input file";
const RECORD_BYTES: u64 = size_of::<InputTriangle>() as u64;
/// Bytes a shard input file holds while it is written: an open file, an LZ4 encoder and its
/// share of a run of triangles (about 2 MB together, measured on a 24-shard plan).
pub const INPUT_WRITER_BYTES: u64 = 5 << 19;
/// The most files written by one pass over the scene: many shards take several passes.
pub const MAX_FILES_PER_PASS: usize = 128;
/// Triangles gathered before the files compress them.
const TRIANGLES_PER_RUN: usize = 1 << 16;

/// How many of `scene`'s triangles each shard of `plan` reads: those with a corner under
/// one of its roots (`root_of`, from [`super::roots_of_vertices`]).
pub fn shard_triangle_counts(
    scene: &impl PlanScene,
    plan: &Plan,
    root_of: &[u32],
) -> Result<Vec<u64>, ShardError> {
    let shard_of_root = shard_of_root(plan);
    let mut counts = vec![0u64; plan.shard_count() as usize];
    scene.for_each_triangle_run(&mut |_, triangles, _| {
        for t in triangles {
            for_each_shard(t, root_of, &shard_of_root, |k| counts[k] += 1);
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

/// Calls `f` once for each shard a triangle's corners lie in.
fn for_each_shard(t: &[u32; 3], root_of: &[u32], shard_of_root: &[u32], mut f: impl FnMut(usize)) {
    let mut shards = t.map(|v| shard_of_root[root_of[v as usize] as usize]);
    shards.sort_unstable();
    for (k, &shard) in shards.iter().enumerate() {
        if k == 0 || shards[k - 1] != shard {
            f(shard as usize);
        }
    }
}

/// Writes every shard's input file (`paths[k]` for shard `k`) from `scene`, each written
/// beside its target and renamed into place when complete, at most `files_per_pass` (1 to
/// [`MAX_FILES_PER_PASS`]; each holds about [`INPUT_WRITER_BYTES`]) in one pass over the
/// scene's triangles. `on_progress(done, total)` is told how many triangles the passes over
/// the scene have gone through.
pub fn write_shard_inputs(
    scene: &impl PlanScene,
    plan: &Plan,
    root_of: &[u32],
    paths: &[PathBuf],
    files_per_pass: usize,
    mut on_progress: impl FnMut(u64, u64),
) -> Result<(), ShardError> {
    let files_per_pass = files_per_pass.clamp(1, MAX_FILES_PER_PASS);
    let shard_of_root = shard_of_root(plan);
    let passes = paths.len().div_ceil(files_per_pass) as u64;
    let total = passes * scene.triangle_count();
    let positions = scene.positions();
    let mut done = 0u64;
    for first in (0..paths.len()).step_by(files_per_pass) {
        let batch = first..(first + files_per_pass).min(paths.len());
        let mut files = batch
            .clone()
            .map(|k| BodyWriter::create(&paths[k], INPUT_MAGIC, k as u32, plan.id))
            .collect::<Result<Vec<_>, _>>()?;
        // A run of triangles at a time: gathered per file, a piece of the run on each thread,
        // then each file compresses its share on its own task (the files are independent
        // streams, each still written in scene order: its pieces one after the other).
        let pieces = rayon::current_num_threads().max(1);
        let mut gathered: Vec<Vec<Vec<u8>>> = vec![vec![Vec::new(); batch.len()]; pieces];
        scene.for_each_triangle_run(&mut |run_first, triangles, parts| {
            for (sub, (triangles, parts)) in triangles
                .chunks(TRIANGLES_PER_RUN)
                .zip(parts.chunks(TRIANGLES_PER_RUN))
                .enumerate()
            {
                let sub_first = run_first + (sub * TRIANGLES_PER_RUN) as u64;
                // Triangles with a part each (as the zip of the two would take them).
                let n = triangles.len().min(parts.len());
                let (triangles, parts) = (&triangles[..n], &parts[..n]);
                let piece = triangles.len().div_ceil(pieces);
                gathered
                    .par_iter_mut()
                    .enumerate()
                    .for_each(|(p, gathered)| {
                        let start = (p * piece).min(triangles.len());
                        let end = (start + piece).min(triangles.len());
                        let mine = triangles[start..end].iter().zip(&parts[start..end]);
                        for (i, (&t, &part)) in (start..).zip(mine) {
                            for_each_shard(&t, root_of, &shard_of_root, |k| {
                                if batch.contains(&k) {
                                    let id = sub_first + i as u64;
                                    let record = input_triangle(id, part, t, positions);
                                    gathered[k - first].extend_from_slice(record.as_bytes());
                                }
                            });
                        }
                    });
                files.par_iter_mut().enumerate().try_for_each(|(j, file)| {
                    for piece in &gathered {
                        file.put(&piece[j])?;
                    }
                    Ok::<(), ShardError>(())
                })?;
                for piece in &mut gathered {
                    piece.iter_mut().for_each(Vec::clear);
                }
                done += triangles.len() as u64;
                on_progress(done, total);
            }
            Ok(())
        })?;
        for file in files {
            file.finish()?;
        }
    }
    Ok(())
}

/// Reads shard `index`'s input file, which must be for `plan`.
pub fn read_shard_input(
    path: &Path,
    plan: &Plan,
    index: u32,
) -> Result<Vec<InputTriangle>, ShardError> {
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
    let Some(&count) = plan.shard_triangles.get(index as usize) else {
        return Err(bad(
            "the plan does not say how many triangles its shards read".into(),
        ));
    };
    if trailer.body_bytes != count * RECORD_BYTES {
        return Err(bad(format!(
            "{} bytes of triangles; the plan gives this shard {count} triangles",
            trailer.body_bytes
        )));
    }
    // The count comes from the plan, a file: a plan stating more than memory holds gets an
    // error, not an abort.
    let mut triangles = Vec::new();
    triangles
        .try_reserve_exact(count as usize)
        .map_err(|_| bad(format!("{count} triangles do not fit in memory")))?;
    triangles.resize(count as usize, InputTriangle::new_zeroed());
    read_body_into(path, &trailer, triangles.as_mut_bytes())?;
    Ok(triangles)
}
