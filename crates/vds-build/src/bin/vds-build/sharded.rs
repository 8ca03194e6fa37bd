//! `vds-build plan | shard | merge`: the sharded build as independent jobs, for a batch
//! scheduler (a job array, an indexed job, GNU parallel) or plain background processes.
//!
//! ```text
//! vds-build plan INPUT... --shards N -o plan.json
//! vds-build shard plan.json --index K -o shard-K.vdtpart      # K = 0 .. N-1, in any order
//! vds-build merge plan.json shard-*.vdtpart -o OUT.vdt
//! ```
//!
//! The output is the file `vds-build INPUT... -o OUT.vdt` writes, byte for byte.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use vds_build::shard::{self, Durability, Plan, PlanMetadata};
use vds_import::{SpilledScene, Weld};

use crate::{ImportLimits, MAX_THREADS, PageOptions, check_output, hash_files_aside};

/// The first arguments that select the sharded build's commands.
pub const COMMANDS: [&str; 3] = ["plan", "shard", "merge"];

#[derive(Parser, Debug)]
#[command(
    name = "vds-build",
    version,
    about = "Build a vertex tree as independent jobs: plan, shards, merge"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Worker threads per job, 1 to 1024 (default: all cores).
    #[arg(long, global = true, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_THREADS))]
    threads: Option<usize>,
    /// Print nothing but errors.
    #[arg(long, short, global = true)]
    quiet: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Read the inputs and plan the shards: the file's grid, the tree's top levels and which
    /// shard builds which part of the model.
    Plan {
        /// Input meshes, as for an in-memory build.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Number of shards (independent jobs), 1 to 4096.
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4096))]
        shards: u32,
        /// The plan file to write.
        #[arg(short, long, value_name = "PLAN.json")]
        output: PathBuf,
        #[command(flatten)]
        pages: PageOptions,
        #[command(flatten)]
        limits: ImportLimits,
    },
    /// Build one shard of a plan.
    Shard {
        /// The plan.
        plan: PathBuf,
        /// Which shard, from 0.
        #[arg(long)]
        index: u32,
        /// The part file to write.
        #[arg(short, long, value_name = "SHARD.vdtpart")]
        output: PathBuf,
    },
    /// Join every shard's part into the .vdt file.
    Merge {
        /// The plan.
        plan: PathBuf,
        /// Every shard's part file, once each, in any order.
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        /// The .vdt file to write.
        #[arg(short, long, value_name = "OUT.vdt")]
        output: PathBuf,
        /// Check the written file as `vds-info --verify` does.
        #[arg(long)]
        verify: bool,
    },
}

/// Runs `vds-build plan | shard | merge` with the process's arguments.
pub fn main() -> Result<()> {
    let cli = Cli::parse();
    if let Some(threads) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()
            .context("cannot set up the thread pool")?;
    }
    let start = Instant::now();
    let progress = Progress::new(!cli.quiet && std::io::stderr().is_terminal());
    let say = |what: String| {
        progress.clear();
        if !cli.quiet {
            eprintln!(
                "vds-build: {what} in {:.2} s",
                start.elapsed().as_secs_f64()
            );
        }
    };
    match cli.command {
        Command::Plan {
            inputs,
            shards,
            output,
            pages,
            limits,
        } => {
            check_output(&output, &inputs)?;
            let options = limits.options(Weld::Exact);
            progress.phase("reading meshes");
            let hashes = hash_files_aside(&inputs);
            let mut scene = vds_import::spill_files(&inputs, &options, &folder_of(&output))?;
            if !cli.quiet {
                for warning in &scene.warnings {
                    progress.print(&format!("vds-build: warning: {warning}"));
                }
            }
            progress.phase("planning the top of the tree");
            let basis = plan_basis(&mut scene, &inputs, hashes, pages)?;
            let planned = plan_scene(&scene, &basis, &inputs, shards, &output)?;
            let plan = write_plan(
                scene,
                planned,
                &output,
                shard::MAX_FILES_PER_PASS,
                &progress,
            )?;
            say(format!(
                "planned {} shards of {} roots ({} vertices, {} triangles)",
                plan.shard_count(),
                plan.roots.len(),
                plan.vertices,
                plan.triangles
            ));
        }
        Command::Shard {
            plan,
            index,
            output,
        } => {
            let plan_path = plan;
            let plan = load_plan(&plan_path)?;
            if index >= plan.shard_count() {
                bail!(
                    "--index {index}: the plan has shards 0 to {}",
                    plan.shard_count() - 1
                );
            }
            let Some(name) = plan.input_files.get(index as usize) else {
                bail!(
                    "{}: names no input files for its shards",
                    plan_path.display()
                );
            };
            let input_file = folder_of(&plan_path).join(name);
            check_output(&output, &[input_file.clone(), plan_path.clone()])?;
            progress.phase("building the shard's subtrees");
            let cross = build_shard_file(&plan, &input_file, index, &output, Durability::Synced)?;
            say(format!(
                "built shard {index} of {} ({} roots, {cross} corners of triangles across roots)",
                plan.shard_count(),
                plan.shard_roots(index).len(),
            ));
        }
        Command::Merge {
            plan,
            parts,
            output,
            verify,
        } => {
            let plan_path = plan;
            let plan = load_plan(&plan_path)?;
            let mut inputs = parts.clone();
            inputs.push(plan_path);
            check_output(&output, &inputs)?;
            let parts = parts_in_order(&plan, &parts)?;
            let report = merge_parts(&plan, &parts, &output, &progress)?;
            if verify {
                let verified = vds_format::VdtFile::open(&output)
                    .map_err(vds_build::VerifyError::from)
                    .and_then(|file| vds_build::verify_file(&file));
                if let Err(error) = verified {
                    let _ = std::fs::remove_file(&output);
                    return Err(error)
                        .with_context(|| format!("{}: does not verify", output.display()));
                }
            }
            say(format!(
                "merged {} shards into {} ({} bytes, {} pages)",
                plan.shard_count(),
                output.display(),
                report.file_bytes,
                report.pages
            ));
        }
    }
    Ok(())
}

/// A planned build of an imported scene, not yet written: the plan and where each shard's
/// input goes (`PLAN.shard-K.vdtin` beside the plan).
pub(crate) struct Planned {
    pub(crate) plan: Plan,
    input_paths: Vec<PathBuf>,
    /// Each vertex's root, for writing the inputs.
    root_of: Vec<u32>,
}

/// What every plan of an imported scene starts from: its grid (the scene snapped to it) and
/// the metadata, the input files' hashes included.
pub(crate) struct PlanBasis {
    grid: vds_format::Grid,
    metadata: PlanMetadata,
}

/// The inputs' hashes, taken while the scene is read ([`hash_files_aside`]).
pub(crate) type InputHashes = std::thread::JoinHandle<Result<Vec<(u64, u64)>>>;

/// Snaps `scene` to its grid and reads what its plans record; `hashes` are the inputs'.
pub(crate) fn plan_basis(
    scene: &mut SpilledScene,
    inputs: &[PathBuf],
    hashes: InputHashes,
    pages: PageOptions,
) -> Result<PlanBasis> {
    let grid = vds_build::snap_positions(&mut scene.positions);
    let hashes = hashes.join().expect("hashing a file does not panic")?;
    let files = inputs
        .iter()
        .zip(hashes)
        .map(|(input, (content_hash, bytes))| (file_name(input), bytes, content_hash))
        .collect();
    let metadata = PlanMetadata::of_parts(
        &scene.part_names,
        &scene.parts,
        &scene.stats,
        tool(),
        &pages.write_options(),
        files,
    );
    Ok(PlanBasis { grid, metadata })
}

/// Plans the build of `scene` (snapped by [`plan_basis`]) in `shards` shards, the plan to be
/// written to `plan_path`; the shards' triangle counts are left to [`write_inputs`].
pub(crate) fn plan_scene(
    scene: &SpilledScene,
    basis: &PlanBasis,
    inputs: &[PathBuf],
    shards: u32,
    plan_path: &Path,
) -> Result<Planned> {
    let mut plan = shard::plan(
        &scene.positions,
        scene.triangle_count,
        basis.grid,
        shards,
        basis.metadata.clone(),
    )?;
    let stem = plan_path
        .file_stem()
        .map_or_else(|| "plan".into(), |s| s.to_string_lossy().into_owned());
    plan.input_files = (0..plan.shard_count())
        .map(|k| format!("{stem}.shard-{k}.vdtin"))
        .collect();
    let root_of = shard::roots_of_vertices(scene, &plan)?;
    plan.seal();
    let folder = folder_of(plan_path);
    let input_paths: Vec<PathBuf> = plan
        .input_files
        .iter()
        .map(|name| folder.join(name))
        .collect();
    for path in &input_paths {
        check_output(path, inputs)?;
    }
    Ok(Planned {
        plan,
        input_paths,
        root_of,
    })
}

/// Writes the shards' inputs (`files_per_pass` at a time, each synced where `durability`
/// says), counting each shard's triangles as it goes: the plan records the counts, is
/// sealed with them, and its inputs are named for it.
pub(crate) fn write_inputs(
    scene: &SpilledScene,
    planned: &mut Planned,
    files_per_pass: usize,
    durability: Durability,
    progress: &Progress,
) -> Result<()> {
    let Planned {
        plan,
        input_paths,
        root_of,
    } = planned;
    progress.counted("writing the shards' inputs (triangles)");
    let written_for = plan.id;
    plan.shard_triangles = shard::write_shard_inputs(
        scene,
        plan,
        root_of,
        input_paths,
        files_per_pass,
        durability,
        |done, total| progress.set(done, total),
    )?;
    plan.seal();
    shard::stamp_shard_inputs(input_paths, written_for, plan, durability)?;
    Ok(())
}

/// Writes the plan whose inputs [`write_inputs`] wrote, last, so that a plan on disk always
/// has its shards' inputs.
pub(crate) fn save_plan(planned: Planned, plan_path: &Path) -> Result<Plan> {
    let Planned { plan, .. } = planned;
    plan.save(plan_path)?;
    Ok(plan)
}

/// [`write_inputs`] (synced: later jobs read them), then (with the scene freed)
/// [`save_plan`].
pub(crate) fn write_plan(
    scene: SpilledScene,
    mut planned: Planned,
    plan_path: &Path,
    files_per_pass: usize,
    progress: &Progress,
) -> Result<Plan> {
    write_inputs(
        &scene,
        &mut planned,
        files_per_pass,
        Durability::Synced,
        progress,
    )?;
    drop(scene);
    save_plan(planned, plan_path)
}

/// Builds shard `index` from its input file and writes its part to `output` (synced where
/// `durability` says); returns its count of corners of triangles across roots.
pub(crate) fn build_shard_file(
    plan: &Plan,
    input_file: &Path,
    index: u32,
    output: &Path,
    durability: Durability,
) -> Result<usize> {
    let input = shard::read_shard_input(input_file, plan, index)?;
    Ok(shard::write_shard(output, plan, index, input, durability)?)
}

/// Merges the parts (in shard order) into `output`: each part's head read in the merge's first
/// pass, then the whole part in its second, at most two in memory at a time: the one merged
/// and the next, read beside it.
pub(crate) fn merge_parts(
    plan: &Plan,
    parts: &[&Path],
    output: &Path,
    progress: &Progress,
) -> Result<vds_format::WriteReport> {
    let shards = plan.shard_count();
    progress.counted("joining the parts (shards), then writing their pages");
    let mut file = vds_format::AtomicFile::create(output)?;
    // The merge asks for every part's head, then for every part, in index order. A head is
    // a small read (the file is seeked over its pages and leaves); reading a whole part is
    // a core's work (the file copied out of the page cache, its records checked and its
    // checksum taken), and the merge waited for each: a thread reads the next part while
    // the merge works on the one before (the 20 M scene's merge of 16 parts 1.43-1.47 ->
    // 1.13-1.19 s, peak 84-88 -> 108-111 MB, when the first pass read whole parts too).
    let report = std::thread::scope(|scope| {
        let (send, receive) = std::sync::mpsc::sync_channel(0);
        scope.spawn(move || {
            // From the arena the other threads of a build within `--memory-limit` share (for a
            // merge job alone, the main thread's arena: no matter).
            crate::allocator::share_one_arena();
            for k in 0..shards {
                let part = shard::read_part_checked(parts[k as usize], plan);
                // The merge stopped (an error): nothing more is wanted.
                if send.send((k, part)).is_err() {
                    break;
                }
            }
        });
        let mut expected = 0..shards;
        shard::merge_to(
            plan,
            |k| {
                progress.set(u64::from(k), 2 * u64::from(shards));
                shard::read_part_head(parts[k as usize], plan)
            },
            |k| {
                let want = expected.next().expect("each part asked for once");
                progress.set(u64::from(shards + k), 2 * u64::from(shards));
                let (read, part) = receive
                    .recv()
                    .expect("the reader reads every part the merge asks for");
                assert!(
                    want == k && read == k,
                    "the merge asks for the parts in the order they are read"
                );
                part
            },
            &mut file,
            // Beside the output, not in TMPDIR, which may be memory.
            &folder_of(output),
        )
        // `receive` is dropped as this returns: a reader still holding a part that nobody
        // will ask for (after an error) stops, and the scope's wait for it ends.
    })
    // The first pass reads heads unverified: a damaged part can make the parts disagree
    // before the second pass would have found its checksum wrong. The file is named then.
    .or_else(|error| match error {
        shard::ShardError::PartSet(_) => {
            for part in parts {
                shard::read_part_checked(part, plan)?;
            }
            Err(error)
        }
        other => Err(other),
    })
    .with_context(|| format!("cannot merge into {}", output.display()))?;
    file.commit()?;
    Ok(report)
}

/// What a terminal shows while a job runs: a spinner naming the phase, or a bar with an ETA
/// where the work is counted. Nothing when stderr is not a terminal or with `--quiet`.
pub(crate) struct Progress {
    bar: Option<indicatif::ProgressBar>,
}

impl Progress {
    pub(crate) fn new(enabled: bool) -> Progress {
        Progress {
            bar: enabled.then(|| {
                let bar = indicatif::ProgressBar::new_spinner();
                bar.enable_steady_tick(std::time::Duration::from_millis(100));
                bar
            }),
        }
    }

    /// A phase whose work is not counted.
    pub(crate) fn phase(&self, message: &'static str) {
        if let Some(bar) = &self.bar {
            bar.set_style(indicatif::ProgressStyle::default_spinner());
            bar.set_message(message);
        }
    }

    /// A counted phase: [`Progress::set`] moves its bar.
    pub(crate) fn counted(&self, message: &'static str) {
        if let Some(bar) = &self.bar {
            let style = indicatif::ProgressStyle::with_template(
                "{msg} [{bar:30}] {human_pos}/{human_len}, {eta} left",
            )
            .expect("a valid template")
            .progress_chars("=> ");
            bar.set_style(style);
            bar.set_message(message);
            bar.set_position(0);
        }
    }

    pub(crate) fn set(&self, done: u64, total: u64) {
        if let Some(bar) = &self.bar {
            bar.set_length(total);
            bar.set_position(done);
        }
    }

    pub(crate) fn clear(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }

    /// Prints a line on stderr above the bar.
    pub(crate) fn print(&self, line: &str) {
        match &self.bar {
            Some(bar) => bar.suspend(|| eprintln!("{line}")),
            None => eprintln!("{line}"),
        }
    }
}

/// The part files in shard order, after checking from their headers that they are the
/// plan's shards, each once.
fn parts_in_order<'a>(plan: &Plan, paths: &'a [PathBuf]) -> Result<Vec<&'a Path>> {
    let mut owner: Vec<Option<&Path>> = vec![None; plan.shard_count() as usize];
    for path in paths {
        let (index, plan_id) = shard::part_header(path)?;
        if plan_id != plan.id {
            bail!(
                "{}: built for another plan (id {plan_id:016x}, this plan is {:016x})",
                path.display(),
                plan.id
            );
        }
        match owner.get_mut(index as usize) {
            Some(Some(earlier)) => bail!(
                "{} and {} are both shard {index}",
                earlier.display(),
                path.display()
            ),
            Some(slot) => *slot = Some(path),
            None => bail!(
                "{}: shard {index}, but the plan has {}",
                path.display(),
                plan.shard_count()
            ),
        }
    }
    let missing: Vec<String> = owner
        .iter()
        .enumerate()
        .filter(|(_, p)| p.is_none())
        .map(|(k, _)| k.to_string())
        .collect();
    if !missing.is_empty() {
        bail!(
            "missing shard {} of {} (no part file given for it)",
            missing.join(", "),
            plan.shard_count()
        );
    }
    Ok(owner.into_iter().flatten().collect())
}

/// Reads a plan made by this very version: the jobs of one build must all run the same
/// `vds-build`, or the file would be one that no single version writes.
fn load_plan(path: &Path) -> Result<Plan> {
    let plan = Plan::load(path)?;
    if plan.metadata.tool != tool() {
        bail!(
            "{}: made by {}, this is {}; run every job of a build with one version",
            path.display(),
            plan.metadata.tool,
            tool()
        );
    }
    Ok(plan)
}

/// The folder a file is in (`.` for a bare name).
pub(crate) fn folder_of(path: &Path) -> PathBuf {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
}

fn file_name(input: &Path) -> String {
    input.file_name().map_or_else(
        || input.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn tool() -> String {
    format!("vds-build {}", env!("CARGO_PKG_VERSION"))
}
