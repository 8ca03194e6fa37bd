//! `vds-build`: reads meshes (OBJ, glTF/GLB, PLY, STL), builds the global vertex tree and
//! writes it as a `.vdt` file (`-o`), or one file per input (`--batch --out-dir`). With no
//! input it builds the bundled demo assembly and reports what it built.
//!
//! Exit codes: 0 success, 1 an input could not be read, built or written (in batch mode: any
//! input), 2 bad command line (numbers out of range, NaN or infinite included).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use serde::Serialize;
use vds_import::{ImportOptions, Weld};

/// The demo model used when no input is given (a CAD assembly of 18 solids).
const DEMO_MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../testdata/as1_assembly.obj"
);

#[derive(Parser, Debug)]
#[command(
    version,
    about = "Build the VDS vertex tree of one scene from mesh files"
)]
struct Args {
    /// Input meshes (.obj, .gltf, .glb, .ply, .stl, optionally .gz); all merge into one scene.
    /// Without inputs, the bundled demo assembly is built.
    inputs: Vec<PathBuf>,
    /// Write the vertex tree to this .vdt file (a regular file or a new one, never an input).
    #[arg(short, long, value_name = "OUT.vdt", conflicts_with = "batch")]
    output: Option<PathBuf>,
    /// Build each input on its own into DIR/NAME.vdt, going on past failures.
    #[arg(long, requires = "out_dir")]
    batch: bool,
    /// Output directory for --batch.
    #[arg(long, value_name = "DIR")]
    out_dir: Option<PathBuf>,
    #[command(flatten)]
    pages: PageOptions,
    /// Weld vertices closer than this fraction of the bounding-box diagonal, a finite number
    /// from 0 up to (not including) 1 (default: exact).
    #[arg(long, value_name = "EPS", value_parser = weld_fraction)]
    weld: Option<f32>,
    /// How vertices are grouped into the tree: `octree` (tight-octree clustering, fast,
    /// parallel) or `qem` (quadric-ordered pair contraction: budget cuts closer to the
    /// original per triangle, several times slower, one thread).
    #[arg(long, value_name = "octree|qem", default_value = "octree")]
    builder: vds_build::Builder,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_THREADS))]
    threads: Option<usize>,
    /// Print a machine-readable JSON report on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Print nothing but errors.
    #[arg(long, short)]
    quiet: bool,
    /// Check every tree invariant after building and, with -o, the written file as
    /// `vds-info --verify` does (slow on large scenes).
    #[arg(long)]
    verify: bool,
    #[command(flatten)]
    limits: ImportLimits,
    /// Build within this much memory (512MiB, 4GiB): the sharded build (plan, shards, merge)
    /// run by this process, with as many shards as keep them within it; the same file as
    /// without. Takes exact welding and the octree builder. The import spills the model to
    /// disk as it reads it; the plan holds 16 bytes per vertex and 4 per input vertex.
    #[arg(long, value_name = "SIZE", value_parser = parse_size, conflicts_with = "batch", requires = "output")]
    memory_limit: Option<u64>,
}

/// How pages are written (also taken by `vds-build plan`).
#[derive(clap::Args, Debug, Clone, Copy)]
struct PageOptions {
    /// zstd level of the pages (1-22).
    #[arg(long, default_value_t = vds_format::DEFAULT_ZSTD_LEVEL, value_parser = clap::value_parser!(i32).range(1..=22))]
    zstd_level: i32,
    /// Decoded bytes of tree records per page (4KiB to 1MiB; suffixes as for sizes). Smaller
    /// pages let a runtime under a memory budget hold less below its cut, at some cost in
    /// file size.
    #[arg(long, value_name = "SIZE", default_value_t = vds_format::DEFAULT_PAGE_BYTES, value_parser = page_size)]
    page_bytes: u32,
}

impl PageOptions {
    fn write_options(self) -> vds_format::WriteOptions {
        vds_format::WriteOptions {
            zstd_level: self.zstd_level,
            page_bytes: self.page_bytes,
        }
    }
}

/// What the importers refuse (also taken by `vds-build plan`).
#[derive(clap::Args, Debug, Clone, Copy)]
struct ImportLimits {
    /// Refuse inputs holding more triangles than this, all together; glTF instance trees are
    /// counted before they are expanded (default: 2^28 = 268,435,456).
    #[arg(long, value_name = "N", default_value_t = vds_import::ImportOptions::DEFAULT_MAX_TRIANGLES,
          value_parser = clap::value_parser!(u64).range(1..))]
    max_triangles: u64,
    /// Refuse a .gz input that decompresses to more than this, and a glTF whose external
    /// buffer files hold more than this together (bytes, or with a suffix: 512MiB, 8GiB;
    /// default 4GiB). A .gz OBJ is streamed; other .gz inputs go to a temporary file in
    /// TMPDIR; glTF buffers are read into memory.
    #[arg(long, value_name = "SIZE", default_value = "4GiB", value_parser = parse_size)]
    max_decompressed_bytes: u64,
    /// Let glTF buffer URIs name files outside the model's folder (absolute paths, `..`,
    /// links out of the folder, file: URIs). Off by default, so that a model cannot make the
    /// build read other files; other URI schemes are never fetched.
    #[arg(long)]
    allow_external_uris: bool,
}

impl ImportLimits {
    fn options(self, weld: Weld) -> ImportOptions {
        ImportOptions {
            weld,
            max_triangles: self.max_triangles,
            max_decompressed_bytes: self.max_decompressed_bytes,
            allow_external_uris: self.allow_external_uris,
        }
    }
}

/// A byte count: digits, optionally followed by K, M, G or T (powers of 1024), with or
/// without `iB`/`B` (`512MiB`, `2G`, `4096`).
/// `--page-bytes`: a size from 4 KiB to 1 MiB.
fn page_size(text: &str) -> Result<u32, String> {
    let bytes = parse_size(text)?;
    if (4 << 10..=1 << 20).contains(&bytes) {
        Ok(bytes as u32)
    } else {
        Err(format!(
            "expected a page size from 4KiB to 1MiB, got '{text}'"
        ))
    }
}

fn parse_size(text: &str) -> Result<u64, String> {
    let text = text.trim();
    let digits = text
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(text.len());
    let (number, unit) = text.split_at(digits);
    let number: u64 = number
        .parse()
        .map_err(|_| format!("'{text}' is not a size (digits, then K, M, G or T)"))?;
    let shift = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => return Err(format!("'{text}': unknown unit '{unit}' (K, M, G or T)")),
    };
    number
        .checked_mul(1 << shift)
        .filter(|&n| n > 0)
        .ok_or_else(|| format!("'{text}' is zero or too large"))
}

/// The most worker threads `--threads` accepts: far above any core count the builder scales
/// to, and low enough that starting them is instant (100 000 took over a minute).
const MAX_THREADS: u64 = 1024;

/// `--weld`: a finite fraction of the diagonal in `[0, 1)` (1 or more would weld everything
/// into one vertex; NaN would compare false everywhere).
fn weld_fraction(text: &str) -> Result<f32, String> {
    match text.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && (0.0..1.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!(
            "expected a finite number from 0 up to (not including) 1, got {v}"
        )),
        Err(e) => Err(format!("expected a number, got {text:?}: {e}")),
    }
}

/// Refuses, before any work, an output that would replace an input (the same file by device
/// and inode, however either is spelt, through links too) or that is not a regular file.
fn check_output(output: &Path, inputs: &[PathBuf]) -> Result<()> {
    vds_format::resolve_output(output)?;
    if let Some(input) = inputs
        .iter()
        .find(|input| vds_format::same_file(input, output).unwrap_or(false))
    {
        bail!(
            "{}: is the input {}; refusing to overwrite it",
            output.display(),
            input.display()
        );
    }
    Ok(())
}

#[derive(Serialize)]
struct Report {
    inputs: Vec<String>,
    vertices: usize,
    triangles: usize,
    parts: usize,
    input_vertices: u64,
    input_triangles: u64,
    welded_vertices: u64,
    degenerate_triangles_dropped: u64,
    /// `octree` or `qem`.
    builder: &'static str,
    nodes: usize,
    depth: usize,
    degree_histogram: [u64; 9],
    /// What could not be read but cost only colours (a material library, a texture).
    warnings: Vec<String>,
    seconds: Phases,
    triangles_per_second: f64,
    peak_rss_bytes: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    output: Option<FileReport>,
}

#[derive(Serialize)]
struct FileReport {
    path: String,
    bytes: u64,
    pages: u32,
    raw_page_bytes: u64,
    compressed_page_bytes: u64,
    bytes_per_input_triangle: f64,
    write_seconds: f64,
}

#[derive(Serialize)]
struct Phases {
    import: f64,
    cluster: f64,
    adjacency: f64,
    attributes: f64,
    subtris: f64,
    total: f64,
}

/// Peak resident set size of this process (Linux `VmHWM`), if known.
fn peak_rss_bytes() -> Option<u64> {
    memory_status("VmHWM")
}

/// A byte count of this process's `/proc/self/status` (`VmHWM`, `VmRSS`), if known.
fn memory_status(field: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| {
        l.strip_prefix(field)
            .is_some_and(|rest| rest.starts_with(':'))
    })?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

mod allocator;
mod limited;
mod sharded;

fn main() {
    let first = std::env::args_os().nth(1);
    if first.is_some_and(|a| sharded::COMMANDS.iter().any(|c| a == *c)) {
        allocator::return_freed_memory_after(allocator::JOB_DECAY_MS);
        if let Err(error) = sharded::main() {
            eprintln!("vds-build: error: {error:#}");
            std::process::exit(1);
        }
        return;
    }
    let args = Args::parse();
    if let Err(error) = run(args) {
        eprintln!("vds-build: error: {error:#}");
        std::process::exit(1);
    }
}

fn spinner(enabled: bool, message: &'static str) -> Option<indicatif::ProgressBar> {
    enabled.then(|| {
        let bar = indicatif::ProgressBar::new_spinner().with_message(message);
        bar.enable_steady_tick(std::time::Duration::from_millis(100));
        bar
    })
}

fn run(args: Args) -> Result<()> {
    if let Some(threads) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()
            .context("cannot set up the thread pool")?;
    }
    if args.batch {
        return rayon::scope(|_| run_batch(&args));
    }
    let inputs = if args.inputs.is_empty() {
        vec![PathBuf::from(DEMO_MODEL)]
    } else {
        args.inputs.clone()
    };
    if let (Some(limit), Some(output)) = (args.memory_limit, args.output.as_deref()) {
        return limited::build_within(&args, &inputs, output, limit);
    }
    // On a worker of the pool: the build's parallel steps then start from inside it instead of
    // each handing its work to the pool and waiting on a latch (the bunny's build 7 % faster).
    let report = rayon::scope(|_| build_one(&args, &inputs, args.output.as_deref()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else if !args.quiet {
        print_summary(&report, args.verify);
    }
    Ok(())
}

/// `--batch`: one file per input; failures are reported and counted, not fatal.
fn run_batch(args: &Args) -> Result<()> {
    let out_dir = args
        .out_dir
        .as_ref()
        .expect("clap requires --out-dir with --batch");
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let mut reports = Vec::new();
    let mut failed = 0usize;
    // Inputs of one name in different folders would write one output: the first wins and the
    // others fail, rather than silently replacing it.
    let mut claimed: Vec<(PathBuf, &PathBuf)> = Vec::new();
    for input in &args.inputs {
        let stem = input
            .file_name()
            .map_or_else(|| "model".into(), |n| n.to_string_lossy().into_owned());
        let stem = stem.strip_suffix(".gz").unwrap_or(&stem);
        let stem = stem.rsplit_once('.').map_or(stem, |(s, _)| s);
        let output = out_dir.join(format!("{stem}.vdt"));
        let earlier = claimed.iter().find(|(o, _)| *o == output).map(|(_, i)| *i);
        let built = match earlier {
            Some(earlier) => Err(anyhow::anyhow!(
                "{}: {} is already the output of {}; rename one of them",
                input.display(),
                output.display(),
                earlier.display()
            )),
            None => {
                claimed.push((output.clone(), input));
                check_output(&output, &args.inputs)
                    .and_then(|()| build_one(args, std::slice::from_ref(input), Some(&output)))
            }
        };
        match built {
            Ok(report) => {
                if !args.json && !args.quiet {
                    print_summary(&report, args.verify);
                }
                reports.push(serde_json::to_value(&report)?);
            }
            Err(error) => {
                failed += 1;
                eprintln!("vds-build: error: {error:#}");
                reports.push(serde_json::json!({
                    "inputs": [input.display().to_string()],
                    "error": format!("{error:#}"),
                }));
            }
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    }
    if !args.quiet {
        eprintln!(
            "vds-build: {} built, {failed} failed",
            args.inputs.len() - failed
        );
    }
    if failed > 0 {
        std::process::exit(1);
    }
    Ok(())
}

/// XXH3-64 and size of a file, streamed. Only a regular file is read (as the importer
/// reads), so a FIFO or device among the inputs never blocks or spins the hashing thread.
fn hash_file(path: &std::path::Path) -> Result<(u64, u64)> {
    use std::io::Read;
    let mut file = vds_import::open_regular_file(path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    let mut buffer = vec![0u8; 1 << 18];
    let mut total = 0u64;
    loop {
        let n = file.read(&mut buffer)?;
        if n == 0 {
            break;
        }
        hasher.update(&buffer[..n]);
        total += n as u64;
    }
    Ok((hasher.digest(), total))
}

/// The inputs' hashes and sizes ([`hash_file`]), taken on a thread of their own so that
/// reading the meshes does not wait for them (reading is one thread's work for much of it).
fn hash_files_aside(inputs: &[PathBuf]) -> std::thread::JoinHandle<Result<Vec<(u64, u64)>>> {
    let inputs = inputs.to_vec();
    std::thread::spawn(move || inputs.iter().map(|p| hash_file(p)).collect())
}

/// The input size from which an in-memory build hands its freed memory back before writing
/// (see [`allocator::release_freed_memory`]).
const PURGE_FROM_TRIANGLES: u64 = 1 << 20;

fn build_one(args: &Args, inputs: &[PathBuf], output: Option<&std::path::Path>) -> Result<Report> {
    if let Some(output) = output {
        check_output(output, inputs)?;
    }
    let show_progress = !args.quiet && !args.json && std::io::stderr().is_terminal();
    let options = args
        .limits
        .options(args.weld.map_or(Weld::Exact, Weld::Relative));

    let start = Instant::now();
    // The inputs' hashes (for the metadata) are taken on a thread of their own while the
    // meshes are read: reading an OBJ is one thread's work, and the hash costs the bunny's
    // build 4 % of its time when it waits for its turn.
    let hashes = output.map(|_| hash_files_aside(inputs));
    let bar = spinner(show_progress, "reading meshes");
    let mut scene = vds_import::load_files(inputs, &options)?;
    if !args.quiet {
        for warning in &scene.warnings {
            eprintln!("vds-build: warning: {warning}");
        }
    }
    // A file stores positions on a grid; snap first so the tree's bounds are exact for it.
    let grid = output.map(|_| vds_build::snap_to_grid(&mut scene));
    let import_seconds = start.elapsed().as_secs_f64();
    if let Some(bar) = &bar {
        bar.set_message("building the vertex tree");
    }
    let builder = args.builder;
    let (tree, timings) = vds_build::build_tree_by(&scene, builder);
    if args.verify {
        if let Some(bar) = &bar {
            bar.set_message("verifying the tree");
        }
        vds_build::verify_tree(&tree, &scene).with_context(|| {
            let names: Vec<String> = inputs.iter().map(|p| p.display().to_string()).collect();
            format!("{}: tree invariant broken", names.join(", "))
        })?;
    }
    // What the report needs of the scene, so it can go before the pages are encoded: the
    // writer's triangle records would otherwise sit beside it. (The writer reads the tree's
    // nodes in place, so the tree stays until the file is written.)
    let (vertices, triangles, parts, stats) = (
        scene.positions.len(),
        scene.triangles.len(),
        scene.part_names.len(),
        scene.stats,
    );
    let warnings = std::mem::take(&mut scene.warnings);
    let (nodes, depth, degree_histogram) =
        (tree.node_count(), tree.max_depth(), tree.degree_histogram());
    let file_report = match output {
        Some(path) => {
            if let Some(bar) = &bar {
                bar.set_message("compressing and writing pages");
            }
            let write_start = Instant::now();
            let mut metadata = vds_format::Metadata {
                tool: format!("vds-build {}", env!("CARGO_PKG_VERSION")),
                build: vds_format::BuildInfo {
                    weld: args.weld,
                    zstd_level: args.pages.zstd_level,
                    page_bytes: args.pages.page_bytes,
                },
                part_names: scene.part_names.clone(),
                parts: vds_build::part_records(&scene),
                input_vertices: scene.stats.input_vertices,
                input_triangles: scene.stats.input_triangles,
                degree_histogram,
                ..Default::default()
            };
            let hashes = hashes
                .expect("hashed when an output is given")
                .join()
                .expect("hashing a file does not panic")?;
            for (input, (content_hash, bytes)) in inputs.iter().zip(hashes) {
                metadata.inputs.push(vds_format::InputInfo {
                    // The name alone, no directories, so a build is the same bytes wherever
                    // it runs and however the input is spelt; the hash says which file it was.
                    name: input.file_name().map_or_else(
                        || input.display().to_string(),
                        |n| n.to_string_lossy().into_owned(),
                    ),
                    bytes,
                    content_hash,
                });
            }
            if !tree.nodes.is_empty() {
                let (center, r) = tree.sphere(vds_build::VertexTree::ROOT);
                metadata.bounds_min = [0, 1, 2].map(|k| center[k] - r);
                metadata.bounds_max = [0, 1, 2].map(|k| center[k] + r);
            }
            let grid = grid.expect("snapped when an output is given");
            // Purging returns the build's garbage (octree buffers, accumulators, adjacency)
            // so that it does not add to the writer's peak; below a million triangles that
            // garbage is under about a hundred MB, and the writer faulting the purged pages in
            // again cost more than it saved (the bunny: 0.5 ms of a 30 ms build).
            if stats.input_triangles >= PURGE_FROM_TRIANGLES {
                allocator::release_freed_memory();
            }
            // The writer reads the tree's nodes in place; the scene is done with.
            let content = vds_build::tree_content(&tree, &scene, metadata, grid);
            drop(scene);
            let write_options = args.pages.write_options();
            let written = vds_format::write_file(path, &content, &write_options)
                .with_context(|| format!("cannot write {}", path.display()))?;
            if args.verify {
                // The file read back and checked as `vds-info --verify` does, so a header or
                // metadata figure the writer got wrong cannot pass; one that fails is removed.
                drop(content);
                drop(tree);
                if let Some(bar) = &bar {
                    bar.set_message("verifying the file");
                }
                let verified = vds_format::VdtFile::open(path)
                    .map_err(vds_build::VerifyError::from)
                    .and_then(|file| vds_build::verify_file(&file));
                if let Err(error) = verified {
                    let _ = std::fs::remove_file(path);
                    return Err(error)
                        .with_context(|| format!("{}: does not verify", path.display()));
                }
            }
            Some(FileReport {
                path: path.display().to_string(),
                bytes: written.file_bytes,
                pages: written.pages,
                raw_page_bytes: written.raw_page_bytes,
                compressed_page_bytes: written.compressed_page_bytes,
                bytes_per_input_triangle: written.file_bytes as f64
                    / stats.input_triangles.max(1) as f64,
                write_seconds: write_start.elapsed().as_secs_f64(),
            })
        }
        None => None,
    };
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let total = start.elapsed().as_secs_f64();
    Ok(Report {
        inputs: inputs.iter().map(|p| p.display().to_string()).collect(),
        vertices,
        triangles,
        parts,
        input_vertices: stats.input_vertices,
        input_triangles: stats.input_triangles,
        welded_vertices: stats.welded_vertices,
        degenerate_triangles_dropped: stats.degenerate_triangles_dropped,
        builder: builder.name(),
        warnings,
        nodes,
        depth,
        degree_histogram,
        seconds: Phases {
            import: import_seconds,
            cluster: timings.cluster.as_secs_f64(),
            adjacency: timings.adjacency.as_secs_f64(),
            attributes: timings.attributes.as_secs_f64(),
            subtris: timings.subtris.as_secs_f64(),
            total,
        },
        triangles_per_second: stats.input_triangles as f64 / total,
        peak_rss_bytes: peak_rss_bytes(),
        output: file_report,
    })
}

fn print_summary(report: &Report, verified: bool) {
    println!(
        "{}: {} vertices, {} triangles, {} parts ({} vertices welded, {} degenerate triangles dropped)",
        report.inputs.join(", "),
        report.vertices,
        report.triangles,
        report.parts,
        report.welded_vertices,
        report.degenerate_triangles_dropped,
    );
    println!(
        "vertex tree: {} nodes, depth {}, degrees {:?}{}",
        report.nodes,
        report.depth,
        &report.degree_histogram[..],
        if verified {
            ", all invariants hold"
        } else {
            ""
        }
    );
    if let Some(file) = &report.output {
        println!(
            "wrote {}: {} bytes in {} pages ({:.1} bytes per input triangle)",
            file.path, file.bytes, file.pages, file.bytes_per_input_triangle
        );
    }
    println!(
        "time: import {:.3} s, cluster {:.3} s, attributes {:.3} s, subtris {:.3} s, total {:.3} s ({:.2} M triangles/s)",
        report.seconds.import,
        report.seconds.cluster,
        report.seconds.attributes,
        report.seconds.subtris,
        report.seconds.total,
        report.triangles_per_second / 1e6
    );
}
