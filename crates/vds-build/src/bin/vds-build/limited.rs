//! `vds-build INPUT... -o OUT.vdt --memory-limit SIZE`: the sharded build (plan, shards,
//! merge) run by this one process, with shards enough to keep the shards and the merge within
//! the limit. The file is the in-memory build's, byte for byte.
//!
//! The shard count comes from what the jobs were measured to hold (`docs/benchmarks.md`,
//! "Sharded build"): a shard about 140–150 bytes per triangle it reads when another runs
//! beside it, the merge about 175 bytes per triangle of the part it holds, and the next part.
//! Shards run side by side, as many as the cores and the limit allow. Their inputs and parts,
//! and the merge's spilled pages, go beside the output (not `TMPDIR`, which may be memory)
//! and are removed at the end. The import spills the model to that folder as it reads it and
//! welds it there ([`vds_import::spill_files`]); the
//! plan then holds 16 bytes per welded vertex (position, root) and 4 per input vertex (weld).
//! The build reports the import's and plan's peak and the shards' and merge's apart, and warns
//! when either is over the limit.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use vds_build::shard::{self, Durability, Plan};
use vds_import::Weld;

use crate::sharded::{
    Progress, build_shard_file, folder_of, merge_parts, plan_basis, plan_scene, save_plan,
    write_inputs,
};
use crate::{Args, check_output, memory_status, peak_rss_bytes};

/// Bytes a shard holds per triangle it reads, with a margin over the 140–150 measured with
/// two shards side by side in one process (a shard job alone holds about 113: side by side,
/// the pages one frees wait up to [`crate::allocator::LIMITED_DECAY_MS`] for reuse).
const SHARD_BYTES_PER_TRIANGLE: u64 = 160;
/// Bytes the merge holds per triangle of the part it reads, with a margin over the 175
/// measured, and the next part, read beside it: about 5-20 bytes per triangle more (the
/// 10 M scene's merge of 2 parts peaked at 117-118 MB, from 90-94). (Making a part's pages
/// side by side holds them until they are spilled: the merge job of the 20 M scene's 8
/// parts then peaked at 107 MB, from 94.)
const MERGE_BYTES_PER_TRIANGLE: u64 = 220;
/// Bytes a shard job holds whatever its size (its zstd contexts, buffers, the allocator's
/// caches of its threads).
const SHARD_OVERHEAD_BYTES: u64 = 8 << 20;
/// Quarters of the limit past which a finished shard returns the freed pages the allocator
/// keeps ([`crate::allocator::LIMITED_DECAY_MS`]): the shard counts leave the shards room
/// for their own arrays, not for pages kept after them.
const PURGE_ABOVE_QUARTERS: u64 = 3;
/// The most shards a plan has.
const MAX_SHARDS: u32 = 4096;

/// What `--json` prints for a build within a memory limit.
#[derive(Serialize)]
struct LimitedReport {
    inputs: Vec<String>,
    vertices: u32,
    triangles: u64,
    memory_limit_bytes: u64,
    shards: u32,
    /// Shards built side by side.
    concurrent_shards: usize,
    seconds: LimitedPhases,
    triangles_per_second: f64,
    /// Peak resident memory of the whole process, of the import and planning, and of the
    /// shards and the merge (from when the scene was freed).
    peak_rss_bytes: Option<u64>,
    import_peak_rss_bytes: Option<u64>,
    shards_and_merge_peak_rss_bytes: Option<u64>,
    output: LimitedOutput,
}

#[derive(Serialize)]
struct LimitedPhases {
    import_and_plan: f64,
    shards: f64,
    merge: f64,
    total: f64,
}

#[derive(Serialize)]
struct LimitedOutput {
    path: String,
    bytes: u64,
    pages: u32,
}

/// How many shards can run side by side on `threads` cores within `budget` bytes whatever
/// their size: as many as the cores, but no more than leave half the budget after their
/// fixed overheads.
fn side_by_side_at_most(threads: usize, budget: u64) -> u64 {
    (threads.max(1) as u64)
        .min(budget / 2 / SHARD_OVERHEAD_BYTES)
        .max(1)
}

/// The shard count the plan tries first for `triangles` on `threads` cores within `budget`
/// bytes: enough for as many shards side by side as [`side_by_side_at_most`] allows, each
/// with its fixed overhead, and for the merge, when the largest shard is an eighth over the
/// mean (the generated scenes' are 4–5 % over); past that many shards, rounded up to a
/// multiple of it so that the last shards built side by side finish together. A guess short
/// of that makes the plan cut the model again: 0.6 s of the 20 M scene's 11.5 s in 512 MiB.
fn first_shard_count(triangles: u64, threads: usize, budget: u64) -> u32 {
    let most = u64::from(MAX_SHARDS);
    let side_by_side = side_by_side_at_most(threads, budget);
    // The bytes of the largest of `n` shards (an eighth over the mean), times `n`.
    let largest_bytes =
        |per_triangle: u64| (triangles.saturating_mul(per_triangle) / 8).saturating_mul(9);
    let for_merge = largest_bytes(MERGE_BYTES_PER_TRIANGLE).div_ceil(budget.max(1));
    let for_shards = largest_bytes(side_by_side * SHARD_BYTES_PER_TRIANGLE).div_ceil(
        budget
            .saturating_sub(side_by_side * SHARD_OVERHEAD_BYTES)
            .max(1),
    );
    let mut shards = for_merge.max(for_shards).clamp(1, most);
    if shards > side_by_side {
        shards = (shards.div_ceil(side_by_side) * side_by_side).min(most);
    }
    u32::try_from(shards).expect("at most MAX_SHARDS")
}

/// Restarts the count of the process's peak resident memory (`VmHWM`) from what it holds
/// now (Linux ≥ 4.0: writing 5 to `/proc/self/clear_refs`); false where it cannot.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Runs the build of `inputs` into `output` within `limit` bytes.
pub(crate) fn build_within(
    args: &Args,
    inputs: &[PathBuf],
    output: &Path,
    limit: u64,
) -> Result<()> {
    if args.weld.is_some() {
        bail!(
            "--memory-limit welds exactly (a tolerance weld can join vertices across shards): drop --weld"
        );
    }
    if args.builder != vds_build::Builder::Octree {
        bail!(
            "--memory-limit builds with the octree builder only (pair contraction is one global heap)"
        );
    }
    if args.verify {
        bail!("--verify is not taken with --memory-limit: check the file with `vds-info --verify`");
    }
    check_output(output, inputs)?;
    let start = Instant::now();
    // Every thread of the build on one arena, so that what one frees another reuses
    // (`allocator`); the import and plan return freed pages at once. Starting the pool's
    // workers here also counts their stacks in what the process holds before any work (code,
    // stacks), to which the reserve adds room for the merge's top of the tree and triangles
    // across shards.
    crate::allocator::return_freed_memory_after(0);
    crate::allocator::share_one_arena();
    rayon::broadcast(|_| crate::allocator::share_one_arena());
    let reserve = memory_status("VmRSS").unwrap_or(0) + (16 << 20);
    let Some(budget) = limit.checked_sub(reserve).filter(|&b| b >= 8 << 20) else {
        bail!(
            "--memory-limit {limit}: too small; this process alone holds {} bytes",
            reserve
        );
    };
    let show = !args.quiet && !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let progress = Progress::new(show);
    progress.phase("reading meshes");
    let options = args.limits.options(Weld::Exact);
    let work = tempfile::Builder::new()
        .prefix(".vds-build-")
        .tempdir_in(folder_of(output))
        .with_context(|| format!("cannot make a temporary folder beside {}", output.display()))?;
    let hashes = crate::hash_files_aside(inputs);
    let mut scene = vds_import::spill_files(inputs, &options, work.path())?;
    if !args.quiet {
        for warning in &scene.warnings {
            progress.print(&format!("vds-build: warning: {warning}"));
        }
    }
    progress.phase("planning the shards");
    let plan_path = work.path().join("plan.json");
    let threads = rayon::current_num_threads();
    let basis = plan_basis(&mut scene, inputs, hashes, args.pages)?;
    // Shards enough for one per core to run side by side and for the merge to hold a part,
    // by the measured figures; the plan's shares are only about equal, so its actual shard
    // sizes are checked, and the model cut finer while the merge or a single shard would not
    // fit. Fewer shards run side by side where the limit does not hold one per core.
    let mut shards = first_shard_count(scene.triangle_count, threads, budget);
    let mut previous_largest = u64::MAX;
    // What the plan holds while it writes the shards' inputs (positions, each input vertex's
    // weld and each vertex's root, a run of triangles): the rest of the budget is for the
    // files written at once.
    let holding = scene.positions.len() as u64 * 16 + scene.stats.input_vertices * 4 + (16 << 20);
    let files_per_pass = (budget.saturating_sub(holding) / shard::INPUT_WRITER_BYTES) as usize;
    let (planned, concurrent) = loop {
        // The inputs are written before the shards' sizes are known (the writing counts
        // their triangles, a pass over the model less than counting them first); a plan
        // whose largest shard does not fit is made again finer, and its inputs overwritten
        // (a finer plan has more shards, so every one).
        let mut planned = plan_scene(&scene, &basis, inputs, shards, &plan_path)?;
        // The inputs and parts are the build's own, in its temporary folder: a crash makes
        // them worthless anyway, so they are not synced.
        write_inputs(
            &scene,
            &mut planned,
            files_per_pass,
            Durability::Transient,
            &progress,
        )?;
        let largest = planned
            .plan
            .shard_triangles
            .iter()
            .copied()
            .max()
            .unwrap_or(0);
        let merge_fits = largest * MERGE_BYTES_PER_TRIANGLE <= budget;
        let side_by_side =
            (budget / (largest * SHARD_BYTES_PER_TRIANGLE + SHARD_OVERHEAD_BYTES)) as usize;
        let wanted = (side_by_side_at_most(threads, budget) as usize).min(shards as usize);
        // Cutting finer lets more shards run side by side only while it still shrinks the
        // largest shard (by a quarter at least): past that, fewer run side by side.
        let still_shrinking = largest.saturating_mul(4) < previous_largest.saturating_mul(3);
        if merge_fits
            && side_by_side >= 1
            && (side_by_side >= wanted || !still_shrinking || shards == MAX_SHARDS)
        {
            break (planned, side_by_side.min(wanted));
        }
        // Shards are runs of the plan's roots, which are no smaller than a region of pages:
        // past some count, more shards no longer make smaller ones.
        if shards == MAX_SHARDS || largest >= previous_largest {
            bail!(
                "--memory-limit {limit}: too small for this model; its largest shard reads \
                 {largest} triangles (about {} bytes to merge), and the model cannot be cut \
                 finer{}",
                largest * MERGE_BYTES_PER_TRIANGLE.max(SHARD_BYTES_PER_TRIANGLE),
                if shards < MAX_SHARDS {
                    " (smaller --page-bytes make smaller regions, so smaller shards)"
                } else {
                    ""
                }
            );
        }
        previous_largest = largest;
        shards = shards.saturating_mul(2).min(MAX_SHARDS);
    };
    let vertices = planned.plan.vertices;
    drop(scene);
    let plan = save_plan(planned, &plan_path)?;
    let import_peak = peak_rss_bytes();
    let peak_reset = reset_peak_rss();
    let planned_at = start.elapsed().as_secs_f64();
    if let Some(peak) = import_peak.filter(|&p| p > limit)
        && !args.quiet
    {
        progress.print(&format!(
            "vds-build: warning: reading and planning the model took {} MB, over the limit of \
             {} MB (the plan holds 16 bytes per vertex and 4 per input vertex)",
            peak >> 20,
            limit >> 20
        ));
    }

    // The shards and the merge keep freed pages a moment for reuse.
    crate::allocator::return_freed_memory_after(crate::allocator::LIMITED_DECAY_MS);
    let parts = build_shards(&plan, work.path(), concurrent, limit, &progress)?;
    // The merge's share of the limit assumes no pages kept after the shards.
    crate::allocator::release_freed_memory();
    let shards_at = start.elapsed().as_secs_f64();
    let part_refs: Vec<&Path> = parts.iter().map(PathBuf::as_path).collect();
    let report = merge_parts(&plan, &part_refs, output, &progress)?;
    progress.clear();
    drop(work);
    let total = start.elapsed().as_secs_f64();
    let report = LimitedReport {
        inputs: inputs.iter().map(|p| p.display().to_string()).collect(),
        vertices,
        triangles: plan.triangles,
        memory_limit_bytes: limit,
        shards: plan.shard_count(),
        concurrent_shards: concurrent,
        seconds: LimitedPhases {
            import_and_plan: planned_at,
            shards: shards_at - planned_at,
            merge: total - shards_at,
            total,
        },
        triangles_per_second: plan.metadata.input_triangles as f64 / total,
        peak_rss_bytes: peak_rss_bytes().map(|p| p.max(import_peak.unwrap_or(0))),
        import_peak_rss_bytes: import_peak,
        shards_and_merge_peak_rss_bytes: peak_reset.then(peak_rss_bytes).flatten(),
        output: LimitedOutput {
            path: output.display().to_string(),
            bytes: report.file_bytes,
            pages: report.pages,
        },
    };
    if let Some(peak) = report
        .shards_and_merge_peak_rss_bytes
        .filter(|&p| p > limit)
        && !args.quiet
    {
        eprintln!(
            "vds-build: warning: the shards and the merge took {} MB, over the limit of {} MB",
            peak >> 20,
            limit >> 20
        );
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else if !args.quiet {
        println!(
            "{}: {} vertices, {} triangles; {} shards ({} at a time) within {} MB",
            report.inputs.join(", "),
            report.vertices,
            report.triangles,
            report.shards,
            report.concurrent_shards,
            limit >> 20
        );
        println!(
            "wrote {}: {} bytes in {} pages; peak memory {} MB (import {} MB, shards and merge {} MB)",
            report.output.path,
            report.output.bytes,
            report.output.pages,
            report.peak_rss_bytes.unwrap_or(0) >> 20,
            report.import_peak_rss_bytes.unwrap_or(0) >> 20,
            report.shards_and_merge_peak_rss_bytes.unwrap_or(0) >> 20,
        );
        println!(
            "time: import and plan {:.3} s, shards {:.3} s, merge {:.3} s, total {:.3} s ({:.2} M triangles/s)",
            report.seconds.import_and_plan,
            report.seconds.shards,
            report.seconds.merge,
            report.seconds.total,
            report.triangles_per_second / 1e6
        );
    }
    Ok(())
}

/// Builds every shard of `plan`, `concurrent` at a time, into part files in `folder`. Freed
/// pages the allocator keeps for reuse are returned whenever a shard ends with the process
/// holding more than [`PURGE_ABOVE_QUARTERS`] of `limit`.
fn build_shards(
    plan: &Plan,
    folder: &Path,
    concurrent: usize,
    limit: u64,
    progress: &Progress,
) -> Result<Vec<PathBuf>> {
    let count = plan.shard_count();
    let parts: Vec<PathBuf> = (0..count)
        .map(|k| folder.join(format!("shard-{k}.vdtpart")))
        .collect();
    progress.counted("building the shards");
    let next = AtomicU32::new(0);
    let done = AtomicU32::new(0);
    let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    std::thread::scope(|scope| {
        for _ in 0..concurrent {
            scope.spawn(|| {
                crate::allocator::share_one_arena();
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    if k >= count || failure.lock().expect("not poisoned").is_some() {
                        break;
                    }
                    let input = folder.join(&plan.input_files[k as usize]);
                    let part = &parts[k as usize];
                    if let Err(error) =
                        build_shard_file(plan, &input, k, part, Durability::Transient)
                    {
                        failure.lock().expect("not poisoned").get_or_insert(error);
                        break;
                    }
                    // The input is no longer needed: the disk holds one copy of the model less.
                    let _ = std::fs::remove_file(&input);
                    if memory_status("VmRSS")
                        .is_none_or(|held| held > limit / 4 * PURGE_ABOVE_QUARTERS)
                    {
                        crate::allocator::release_freed_memory();
                    }
                    let finished = done.fetch_add(1, Ordering::Relaxed) + 1;
                    progress.set(u64::from(finished), u64::from(count));
                }
            });
        }
    });
    match failure.into_inner().expect("not poisoned") {
        Some(error) => Err(error),
        None => Ok(parts),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether `shards` shards of `triangles` leave room within `budget` for `side_by_side`
    /// of the largest, an eighth over the mean, and for the merge of one.
    fn fits(triangles: u64, shards: u64, side_by_side: u64, budget: u64) -> bool {
        let largest = triangles as f64 / shards as f64 * 1.125;
        let each = largest * SHARD_BYTES_PER_TRIANGLE as f64 + SHARD_OVERHEAD_BYTES as f64;
        largest * MERGE_BYTES_PER_TRIANGLE as f64 <= budget as f64
            && side_by_side as f64 * each <= budget as f64 * 1.0001
    }

    #[test]
    fn the_first_shard_count_is_the_least_that_fits_in_a_multiple_of_the_shards_side_by_side() {
        for threads in [1usize, 2, 16, 64] {
            for (triangles, budget) in [
                (1_000u64, 64u64 << 20),
                (20_000_000, 491 << 20),
                (200_000_000, 4 << 30),
                (3_000_000_000, 2 << 30),
                (50_000_000, 64 << 20),
            ] {
                let case = format!("{triangles} triangles in {budget} bytes on {threads} cores");
                let shards = u64::from(first_shard_count(triangles, threads, budget));
                let side_by_side = side_by_side_at_most(threads, budget);
                assert!((1..=u64::from(MAX_SHARDS)).contains(&shards), "{case}");
                if shards == u64::from(MAX_SHARDS) {
                    continue;
                }
                assert!(
                    fits(triangles, shards, side_by_side.min(shards), budget),
                    "{case}"
                );
                // The least such count: one step fewer does not fit.
                let step = if shards > side_by_side {
                    assert_eq!(shards % side_by_side, 0, "{case}");
                    side_by_side
                } else {
                    1
                };
                if shards > step {
                    let fewer = shards - step;
                    assert!(
                        !fits(triangles, fewer, side_by_side.min(fewer), budget),
                        "{case}: {fewer} shards would do"
                    );
                }
            }
        }
        // The counts `docs/benchmarks.md` reports on two cores.
        let mib = 1u64 << 20;
        assert_eq!(first_shard_count(20_010_880, 2, 491 * mib), 16);
        assert_eq!(first_shard_count(1_000, 16, 64 * mib), 1);
        // Sixteen cores in 64 MiB: overheads would take the budget, so fewer side by side.
        assert_eq!(side_by_side_at_most(16, 64 * mib), 4);
    }
}
