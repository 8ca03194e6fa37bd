//! `vds-bench`: the builder's benchmark driver. Prints figures; asserts nothing.
//!
//! - The bunny: whole vertex-tree build vs one meshoptimizer `simplify` LOD (and
//!   `simplify_sloppy`) of the same mesh, medians of several runs in one process.
//! - Generated CAD-like scenes (default 1M and 10M triangles): end-to-end `read + weld +
//!   build` throughput and peak memory. Each run is a fresh child process (this binary with
//!   the hidden `one` subcommand), so peak RSS (`VmHWM`) belongs to that run alone.
//! - `vds-bench cut`: the runtime along camera paths and its fidelity (see `cut.rs`).
//! - `vds-bench fidelity`: view-independent cuts against meshoptimizer's `simplify` and
//!   `simplify_sloppy` at equal triangle counts (see `fidelity.rs`).
//! - `vds-bench latency`: the machine's memory latency, to compare machines (`latency.rs`).

mod cut;
mod distance;
mod fidelity;
mod first_touch;
mod latency;
mod read;
mod refine;
mod slack;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use serde::{Deserialize, Serialize};

/// The same allocator as `vds-build`, so the figures are the CLI's.
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

#[derive(Parser)]
#[command(about = "Benchmark the vertex-tree builder")]
struct Args {
    #[command(subcommand)]
    command: Option<Commands>,
    /// Generated scene sizes in triangles (k and M suffixes accepted).
    #[arg(long, value_delimiter = ',', default_value = "1M,10M")]
    sizes: Vec<String>,
    /// Runs per measurement (the median is reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Where generated scenes are cached.
    #[arg(long, default_value = "out/bench")]
    dir: PathBuf,
    /// Directory with the shared meshes (bunny.obj).
    #[arg(long, default_value = "../shared/data")]
    shared: PathBuf,
}

#[derive(Subcommand)]
enum Commands {
    /// (internal) Import and build one file, print a JSON line with times and peak memory.
    #[command(hide = true)]
    One { file: PathBuf },
    /// (internal) Build one file, write its .vdt, time opening and decoding it.
    #[command(hide = true)]
    Vdt { file: PathBuf },
    /// Read speed of the importers (MB/s, triangles/s; parse and check, no weld). Without
    /// files: the bunny's, and the bunny as a whole `vds-build` process against reading it
    /// and one meshoptimizer `simplify` (needs the release `vds-build` binary beside this one).
    Read {
        /// Mesh files to read.
        files: Vec<PathBuf>,
    },
    /// Time dependent random memory reads at several working-set sizes (compare machines
    /// before comparing their figures).
    Latency,
    /// View-independent budget cuts against meshoptimizer's `simplify` and `simplify_sloppy`
    /// at equal triangle counts: two-sided sampled surface distance, mean and max. Default:
    /// the bunny at 1,000 and 5,000, the AS1 assembly at 500 and 2,000, the dragon at 10,000
    /// and 50,000 (from `--shared`).
    Fidelity {
        /// Mesh files, each followed by its targets: `bunny.obj:1000,5000` (default: the
        /// table above).
        meshes: Vec<String>,
    },
    /// Time the first touch of fresh memory, page by page, and a fill of the same memory
    /// once mapped (on the dev VMs the first varies severalfold with what ran before).
    FirstTouch {
        /// How much memory.
        #[arg(long, default_value_t = 1024)]
        megabytes: usize,
    },
    /// Decode every page of a `.vdt` file on one core, reusing one page buffer (as a page
    /// cache would); prints the median of `--runs` passes.
    Decode { file: PathBuf },
    /// Background page loading on a `.vdt` file: open to first frame, time to full
    /// refinement at a fly-through's start and after a 180° turn, pages per second, and
    /// adjust percentiles along the fly-through against the same path fully resident.
    Refine {
        file: PathBuf,
        /// Screen-space threshold in pixels.
        #[arg(long, default_value_t = 1.0)]
        threshold: f32,
        /// Loading threads (default: the cores but one, 1 to 4).
        #[arg(long)]
        threads: Option<usize>,
        /// Milliseconds between frames (a display's pace).
        #[arg(long, default_value_t = 1000.0 / 60.0)]
        pace_ms: f64,
        /// Frames of the fly-through.
        #[arg(long, default_value_t = 600)]
        frames: u32,
        /// Memory budget of the loading runs (the resident comparison has none).
        #[arg(long, default_value = "256MiB", value_parser = vds_runtime::size::parse_size)]
        memory_budget: u64,
        /// Keep corners by rank tracking (no slots) instead of incidence lists.
        #[arg(long)]
        ranks: bool,
        /// Print a line per frame while the start and the turn refine.
        #[arg(long)]
        trace: bool,
        /// Skip the fly-through with every page resident (slow on large files).
        #[arg(long)]
        loading_only: bool,
    },
    /// The runtime: adjust time along camera paths (bunny orbit, generated CAD scene
    /// fly-through) at t = 1 and 5 px, and the bunny's fidelity table (`vds-bench fidelity`).
    Cut {
        /// Frames per camera path.
        #[arg(long, default_value_t = 600)]
        frames: u32,
        /// Generated scene sizes in triangles.
        #[arg(long, value_delimiter = ',', default_value = "1M")]
        sizes: Vec<String>,
        /// Skip the fidelity comparison (slow: exhaustive distances).
        #[arg(long)]
        no_fidelity: bool,
        /// Skip the bunny paths.
        #[arg(long)]
        no_bunny: bool,
        /// Only resident pages, incidence lists and rank tracking: quicker A/B runs.
        #[arg(long)]
        resident_only: bool,
        /// Only rank tracking with resident pages.
        #[arg(long)]
        ranks_only: bool,
        /// Also time a settled check (a second adjust for the same camera) and a re-adjust (a
        /// third) after each resident run.
        #[arg(long)]
        settled: bool,
        /// Fly through this `.vdt` file instead of the bunny and the generated scenes: nothing
        /// is built in the process (quicker runs, and instruction counts of the runtime alone).
        #[arg(long)]
        vdt: Option<PathBuf>,
        /// Threads the threshold pass tests active entries on (folds and unfolds stay on one),
        /// and the sweep from scratch beside it runs on.
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// Also run each resident rank-tracked path adjusting by sweeps from scratch
        /// (`Runtime::set_sweep`).
        #[arg(long)]
        sweep: bool,
        /// Instead of timing, estimate how many frontier tests a per-node slack could skip
        /// along the path, with and without a fold band (`slack.rs`).
        #[arg(long)]
        slack_estimate: bool,
    },
}

#[derive(Serialize, Deserialize)]
struct VdtRun {
    input_triangles: u64,
    file_bytes: u64,
    pages: u32,
    raw_page_bytes: u64,
    write_seconds: f64,
    open_ms: f64,
    /// The same with the file evicted from the page cache first (Linux only).
    cold_open_ms: Option<f64>,
    decode_seconds_one_core: f64,
    decoded_record_bytes: u64,
}

#[derive(Serialize, Deserialize)]
struct OneRun {
    triangles: u64,
    seconds: f64,
    import_seconds: f64,
    build_seconds: f64,
    /// Seconds per build phase: clustering, adjacency, attributes, subtris.
    #[serde(default)]
    phase_seconds: [f64; 4],
    peak_rss_bytes: u64,
}

fn peak_rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |kib| kib * 1024)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn parse_count(text: &str) -> Result<u64> {
    let (digits, scale) = if let Some(d) = text.strip_suffix(['M', 'm']) {
        (d, 1e6)
    } else if let Some(d) = text.strip_suffix(['k', 'K']) {
        (d, 1e3)
    } else {
        (text, 1.0)
    };
    Ok((digits
        .parse::<f64>()
        .with_context(|| format!("bad size '{text}'"))?
        * scale) as u64)
}

fn main() -> Result<()> {
    let args = Args::parse();
    match args.command {
        Some(Commands::One { file }) => return one(&file),
        Some(Commands::Vdt { file }) => return vdt(&file),
        Some(Commands::Decode { file }) => return decode(&file, args.runs),
        Some(Commands::Refine {
            file,
            threshold,
            threads,
            pace_ms,
            frames,
            memory_budget,
            ranks,
            trace,
            loading_only,
        }) => {
            let threads = threads
                .unwrap_or_else(vds_runtime::default_loading_threads)
                .clamp(1, 64);
            if !(0.0..=10_000.0).contains(&pace_ms) {
                bail!("--pace-ms must be from 0 to 10000, got {pace_ms}");
            }
            let options = refine::Options {
                t: threshold,
                threads,
                pace_ms,
                frames: frames.max(2),
                budget: memory_budget,
                tracking: if ranks {
                    vds_runtime::CornerTracking::Ranks
                } else {
                    vds_runtime::CornerTracking::Incidence
                },
                trace,
                loading_only,
            };
            return refine::run(&file, &options);
        }
        Some(Commands::Fidelity { meshes }) => {
            let meshes = if meshes.is_empty() {
                [
                    "bunny.obj:1000,5000",
                    "as1_assembly.obj:500,2000",
                    "dragon.ply.gz:10000,50000",
                ]
                .map(|m| args.shared.join(m).display().to_string())
                .to_vec()
            } else {
                meshes
            };
            for mesh in &meshes {
                let (file, targets) = mesh
                    .rsplit_once(':')
                    .with_context(|| format!("'{mesh}' is not FILE:COUNT,COUNT"))?;
                let targets = targets
                    .split(',')
                    .map(|t| {
                        t.parse::<usize>()
                            .with_context(|| format!("bad count '{t}'"))
                    })
                    .collect::<Result<Vec<_>>>()?;
                fidelity::run(Path::new(file), &targets)?;
            }
            return Ok(());
        }
        Some(Commands::Read { files }) => {
            if !files.is_empty() {
                return read::speeds(&files, args.runs);
            }
            let bunny = args.shared.join("bunny.obj");
            read::speeds(std::slice::from_ref(&bunny), args.runs)?;
            return read::whole_process(&bunny, args.runs.max(9));
        }
        Some(Commands::Latency) => {
            latency::run();
            return Ok(());
        }
        Some(Commands::FirstTouch { megabytes }) => {
            first_touch::run(megabytes);
            return Ok(());
        }
        Some(Commands::Cut {
            frames,
            sizes,
            no_fidelity,
            no_bunny,
            resident_only,
            ranks_only,
            settled,
            vdt,
            threads,
            sweep,
            slack_estimate,
        }) => {
            let runs = cut::Runs {
                resident_only,
                ranks_only,
                settled,
                threads,
                sweep,
                slack_estimate,
            };
            let bunny = args.shared.join("bunny.obj");
            if let Some(vdt) = vdt {
                let bytes =
                    std::fs::read(&vdt).with_context(|| format!("reading {}", vdt.display()))?;
                let name = vdt.display().to_string();
                cut::paths_of_vdt(&name, &bytes, frames, true, runs)?;
            } else {
                if !no_bunny {
                    cut::paths("bunny", &bunny, frames, false, runs)?;
                }
                for size in &sizes {
                    let file = generated_scene(parse_count(size)?, &args.dir)?;
                    cut::paths(
                        &format!("generated CAD scene {size}"),
                        &file,
                        frames,
                        true,
                        runs,
                    )?;
                }
            }
            if !no_fidelity {
                fidelity::run(&bunny, &[1_000, 5_000, 15_000])?;
            }
            return Ok(());
        }
        None => {}
    }
    println!(
        "vds-bench: {} cores, medians of {} runs",
        std::thread::available_parallelism()?,
        args.runs
    );
    // How fast the machine hands out fresh memory just now, in a fresh process as the builds
    // run: on the dev VMs this moves the build figures more than anything else.
    let touch = Command::new(std::env::current_exe()?)
        .arg("first-touch")
        .output()?;
    if touch.status.success() {
        let line = String::from_utf8_lossy(&touch.stdout);
        println!("fresh memory, {}\n", line.trim());
    } else {
        println!("fresh memory: not measured\n");
    }
    bunny(&args.shared.join("bunny.obj"), args.runs)?;
    let mut files = vec![args.shared.join("bunny.obj")];
    for size in &args.sizes {
        files.push(cad_scene(parse_count(size)?, &args.dir, args.runs)?);
    }
    for file in files {
        vdt_figures(&file)?;
    }
    Ok(())
}

/// The hidden `vdt` subcommand: build, write the .vdt beside the input, open and decode it.
fn vdt(file: &Path) -> Result<()> {
    let mut scene = vds_import::load_file(file, &Default::default())?;
    let grid = vds_build::snap_to_grid(&mut scene);
    let tree = vds_build::build_tree(&scene);
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        input_triangles: scene.stats.input_triangles,
        ..Default::default()
    };
    let input_triangles = scene.stats.input_triangles;
    let content = vds_build::tree_content(&tree, &scene, metadata, grid);
    drop(scene);
    let out = std::env::temp_dir().join(format!("vds-bench-{}.vdt", std::process::id()));
    let start = Instant::now();
    let written = vds_format::write_file(&out, &content, &Default::default())?;
    let write_seconds = start.elapsed().as_secs_f64();
    drop(content);
    drop(tree);
    let open_ms = median((0..21).map(|_| open_ms(&out)).collect::<Result<_>>()?);
    let cold_open_ms = cold_open_ms(&out)?;
    let file = vds_format::VdtFile::open(&out)?;
    let decoded_record_bytes = file.header().node_count.get() * vds_format::NODE_BYTES as u64
        + file.header().triangle_count.get() * vds_format::TRIANGLE_BYTES as u64;
    let one_core = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let decode_seconds_one_core = median(
        (0..3)
            .map(|_| {
                let start = Instant::now();
                one_core
                    .install(|| std::hint::black_box(file.read_all_pages().expect("pages decode")));
                start.elapsed().as_secs_f64()
            })
            .collect(),
    );
    std::fs::remove_file(&out)?;
    let run = VdtRun {
        input_triangles,
        file_bytes: written.file_bytes,
        pages: written.pages,
        raw_page_bytes: written.raw_page_bytes,
        write_seconds,
        open_ms,
        cold_open_ms,
        decode_seconds_one_core,
        decoded_record_bytes,
    };
    println!("{}", serde_json::to_string(&run)?);
    Ok(())
}

/// Opening `path` (header, metadata, directory, root page) as a viewer does for a file no
/// process has read lately: the file's pages are dropped from the page cache first (the
/// writer synced them, so they are clean and go), the binary stays warm. Median of 5, in ms.
#[cfg(target_os = "linux")]
fn cold_open_ms(path: &Path) -> Result<Option<f64>> {
    let mut times = Vec::new();
    for _ in 0..5 {
        let evict = std::fs::File::open(path)?;
        rustix::fs::fadvise(&evict, 0, None, rustix::fs::Advice::DontNeed)?;
        times.push(open_ms(path)?);
    }
    Ok(Some(median(times)))
}

/// Milliseconds to open `path` and decode its root page, which any viewer decodes first.
fn open_ms(path: &Path) -> Result<f64> {
    let start = Instant::now();
    let file = vds_format::VdtFile::open(path)?;
    std::hint::black_box(file.read_page(0)?);
    Ok(start.elapsed().as_secs_f64() * 1e3)
}

/// Evicting a file from the page cache is Linux's `posix_fadvise` here: elsewhere no figure.
#[cfg(not(target_os = "linux"))]
fn cold_open_ms(_path: &Path) -> Result<Option<f64>> {
    Ok(None)
}

/// Times decoding every page of `path` on this thread, `runs` times.
fn decode(path: &Path, runs: usize) -> Result<()> {
    let file = vds_format::VdtFile::open(path)?;
    let raw: u64 = file
        .directory()
        .iter()
        .map(|p| u64::from(p.raw_length.get()))
        .sum();
    let compressed: u64 = file
        .directory()
        .iter()
        .map(|p| u64::from(p.compressed_length.get()))
        .sum();
    let triangles = file.header().triangle_count.get() as f64;
    let mut page = file.read_page(0)?;
    // A digest of every decoded record, outside the timing: decoders that change how they
    // decode, but not what, print the same one.
    let mut digest = xxhash_rust::xxh3::Xxh3::new();
    for index in 0..file.directory().len() as u32 {
        file.read_page_into(index, &mut page)?;
        digest.update(zerocopy::IntoBytes::as_bytes(&page.nodes[..]));
        digest.update(zerocopy::IntoBytes::as_bytes(&page.triangles[..]));
    }
    let seconds = median(
        (0..runs.max(1))
            .map(|_| {
                let start = Instant::now();
                for index in 0..file.directory().len() as u32 {
                    file.read_page_into(index, &mut page)
                        .expect("every page decodes");
                    std::hint::black_box(&page);
                }
                start.elapsed().as_secs_f64()
            })
            .collect(),
    );
    // What checksums and zstd alone take, in the same run: the part of the decode time that
    // no page decoder can remove (docs/benchmarks.md, the .vdt section).
    let unpack_seconds = median(
        (0..runs.max(1))
            .map(|_| {
                let start = Instant::now();
                for index in 0..file.directory().len() as u32 {
                    file.with_page_streams(index, |streams| {
                        std::hint::black_box(streams);
                    })
                    .expect("every page decompresses");
                }
                start.elapsed().as_secs_f64()
            })
            .collect(),
    );
    println!(
        "{}: {} pages, {:.1} MB compressed, {:.1} MB of page streams, records digest {:016x}\n  decode on one core {:.3} s (median of {runs}): {:.0} MB/s of page streams, {:.1} M triangles/s\n  checksums and zstd alone {:.3} s: {:.0} MB/s of page streams, {:.0} % of the decode time",
        path.display(),
        file.directory().len(),
        compressed as f64 / 1e6,
        raw as f64 / 1e6,
        digest.digest(),
        seconds,
        raw as f64 / seconds / 1e6,
        triangles / seconds / 1e6,
        unpack_seconds,
        raw as f64 / unpack_seconds / 1e6,
        100.0 * unpack_seconds / seconds
    );
    Ok(())
}

fn vdt_figures(file: &Path) -> Result<()> {
    let exe = std::env::current_exe()?;
    let output = Command::new(&exe).arg("vdt").arg(file).output()?;
    if !output.status.success() {
        bail!(
            "{} failed: {}",
            file.display(),
            String::from_utf8_lossy(&output.stderr)
        );
    }
    let run: VdtRun = serde_json::from_slice(&output.stdout)?;
    let n = run.input_triangles as f64;
    println!(
        ".vdt of {} ({} triangles)",
        file.display(),
        run.input_triangles
    );
    println!(
        "  file {:.1} MB in {} pages: {:.2} bytes/triangle ({:.2} raw)",
        run.file_bytes as f64 / 1e6,
        run.pages,
        run.file_bytes as f64 / n,
        run.raw_page_bytes as f64 / n
    );
    println!(
        "  write (layout + zstd + fsync)   {:7.3} s",
        run.write_seconds
    );
    println!(
        "  open (header, metadata, directory, root page)  {:.3} ms (median of 21)",
        run.open_ms
    );
    if let Some(cold) = run.cold_open_ms {
        println!("  the same, file evicted from the page cache  {cold:.3} ms (median of 5)");
    }
    println!(
        "  decode every page on one core   {:7.3} s  {:6.0} MB/s of page streams (zstd output), {:6.0} MB/s of decoded records, {:5.1} M triangles/s\n",
        run.decode_seconds_one_core,
        run.raw_page_bytes as f64 / run.decode_seconds_one_core / 1e6,
        run.decoded_record_bytes as f64 / run.decode_seconds_one_core / 1e6,
        n / run.decode_seconds_one_core / 1e6
    );
    Ok(())
}

/// The hidden subcommand: one end-to-end build in this process.
fn one(file: &Path) -> Result<()> {
    let start = Instant::now();
    let scene = vds_import::load_file(file, &Default::default())?;
    let import_seconds = start.elapsed().as_secs_f64();
    let build = Instant::now();
    let (tree, timings) = vds_build::build_tree_timed(&scene);
    let build_seconds = build.elapsed().as_secs_f64();
    let seconds = start.elapsed().as_secs_f64();
    std::hint::black_box(&tree);
    let phase_seconds = [
        timings.cluster,
        timings.adjacency,
        timings.attributes,
        timings.subtris,
    ]
    .map(|d| d.as_secs_f64());
    let run = OneRun {
        triangles: scene.stats.input_triangles,
        seconds,
        import_seconds,
        build_seconds,
        phase_seconds,
        peak_rss_bytes: peak_rss_bytes(),
    };
    println!("{}", serde_json::to_string(&run)?);
    Ok(())
}

fn bunny(path: &Path, runs: usize) -> Result<()> {
    let scene = vds_import::load_file(path, &Default::default())
        .with_context(|| format!("the bunny is read from {}", path.display()))?;
    let triangles = scene.triangles.len();
    let time = |f: &mut dyn FnMut()| {
        median(
            (0..runs)
                .map(|_| {
                    let start = Instant::now();
                    f();
                    start.elapsed().as_secs_f64() * 1e3
                })
                .collect(),
        )
    };
    let tree_ms = time(&mut || {
        std::hint::black_box(vds_build::build_tree(&scene));
    });
    let indices: Vec<u32> = scene.triangles.iter().flatten().copied().collect();
    let bytes: &[u8] = bytemuck::cast_slice(&scene.positions);
    let adapter = meshopt::VertexDataAdapter::new(bytes, 12, 0)?;
    let target = 5_000 * 3;
    let simplify_ms = time(&mut || {
        std::hint::black_box(meshopt::simplify(
            &indices,
            &adapter,
            target,
            1.0,
            meshopt::SimplifyOptions::empty(),
            None,
        ));
    });
    let sloppy_ms = time(&mut || {
        std::hint::black_box(meshopt::simplify_sloppy(
            &indices, &adapter, target, 1.0, None,
        ));
    });
    println!("bunny ({triangles} triangles)");
    println!(
        "  vds whole vertex tree      {tree_ms:8.2} ms  {:6.1} M triangles/s",
        triangles as f64 / tree_ms / 1e3
    );
    println!(
        "  meshopt simplify → 5,000   {simplify_ms:8.2} ms  {:6.1} M triangles/s",
        triangles as f64 / simplify_ms / 1e3
    );
    println!("  meshopt simplify_sloppy    {sloppy_ms:8.2} ms");
    println!(
        "  tree / simplify            {:8.2}×\n",
        tree_ms / simplify_ms
    );
    Ok(())
}

/// The generated scene of `triangles` triangles, cached as PLY in `dir`.
fn generated_scene(triangles: u64, dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir)?;
    let file = dir.join(format!("cad-{triangles}.ply"));
    if !file.exists() {
        let scene = vds_gen::generate(triangles);
        let partial = file.with_extension("partial");
        let mut out = std::io::BufWriter::new(std::fs::File::create(&partial)?);
        vds_gen::write_ply(&scene, &mut out)?;
        std::io::Write::flush(&mut out)?;
        drop(out);
        std::fs::rename(&partial, &file)?;
    }
    Ok(file)
}

fn cad_scene(triangles: u64, dir: &Path, runs: usize) -> Result<PathBuf> {
    let file = generated_scene(triangles, dir)?;
    let exe = std::env::current_exe()?;
    let mut results = Vec::new();
    for _ in 0..runs {
        let output = Command::new(&exe).arg("one").arg(&file).output()?;
        if !output.status.success() {
            bail!(
                "{} failed: {}",
                file.display(),
                String::from_utf8_lossy(&output.stderr)
            );
        }
        results.push(serde_json::from_slice::<OneRun>(&output.stdout)?);
    }
    let n = results[0].triangles as f64;
    let seconds = median(results.iter().map(|r| r.seconds).collect());
    let slowest = results.iter().map(|r| r.seconds).fold(0.0, f64::max);
    let import = median(results.iter().map(|r| r.import_seconds).collect());
    let build = median(results.iter().map(|r| r.build_seconds).collect());
    let peak = median(results.iter().map(|r| r.peak_rss_bytes as f64).collect());
    println!(
        "generated CAD scene ({} triangles, {})",
        results[0].triangles,
        file.display()
    );
    println!(
        "  end to end (read + weld + tree) {seconds:7.3} s  {:6.2} M triangles/s",
        n / seconds / 1e6
    );
    println!("    slowest of {runs} runs             {slowest:7.3} s");
    println!("    read + weld                   {import:7.3} s");
    println!(
        "    vertex tree                   {build:7.3} s  {:6.2} M triangles/s",
        n / build / 1e6
    );
    println!(
        "  peak memory                     {:7.1} MB  {:6.1} bytes/triangle\n",
        peak / 1e6,
        peak / n
    );
    Ok(file)
}
