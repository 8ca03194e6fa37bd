//! `vds-build`: reads meshes (OBJ, glTF/GLB, PLY, STL), builds the global vertex tree and
//! reports what it built. With no input it builds the bundled demo assembly.
//!
//! Exit codes: 0 success, 1 an input could not be read or built, 2 bad command line.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use serde::Serialize;
use vds_import::{ImportOptions, Weld};

/// The demo model used when no input is given (a CAD assembly of 18 solids).
const DEMO_MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../testdata/as1_assembly.obj"
);

/// jemalloc, configured in `.cargo/config.toml`: a batch build allocates and frees gigabytes
/// of arrays, and keeping freed pages for reuse avoids faulting them in again.
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "Build the VDS vertex tree of one scene from mesh files"
)]
struct Args {
    /// Input meshes (.obj, .gltf, .glb, .ply, .stl, optionally .gz); all merge into one scene.
    /// Without inputs, the bundled demo assembly is built.
    inputs: Vec<PathBuf>,
    /// Weld vertices closer than this fraction of the bounding-box diagonal (default: exact).
    #[arg(long, value_name = "EPS")]
    weld: Option<f32>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Print a machine-readable JSON report on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Print nothing but errors.
    #[arg(long, short)]
    quiet: bool,
    /// Check every tree invariant after building (slow on large scenes).
    #[arg(long)]
    verify: bool,
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
    nodes: usize,
    depth: usize,
    degree_histogram: [u64; 9],
    seconds: Phases,
    triangles_per_second: f64,
    peak_rss_bytes: Option<u64>,
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
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn main() {
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
    let inputs = if args.inputs.is_empty() {
        vec![PathBuf::from(DEMO_MODEL)]
    } else {
        args.inputs.clone()
    };
    let show_progress = !args.quiet && !args.json && std::io::stderr().is_terminal();
    let options = ImportOptions {
        weld: args.weld.map_or(Weld::Exact, Weld::Relative),
    };

    let start = Instant::now();
    let bar = spinner(show_progress, "reading meshes");
    let scene = vds_import::load_files(&inputs, &options)?;
    let import_seconds = start.elapsed().as_secs_f64();
    if let Some(bar) = &bar {
        bar.set_message("building the vertex tree");
    }
    let (tree, timings) = vds_build::build_tree_timed(&scene);
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let total = start.elapsed().as_secs_f64();
    if args.verify {
        vds_build::verify_tree(&tree, &scene).context("tree invariant broken")?;
    }
    let report = Report {
        inputs: inputs.iter().map(|p| p.display().to_string()).collect(),
        vertices: scene.positions.len(),
        triangles: scene.triangles.len(),
        parts: scene.part_names.len(),
        input_vertices: scene.stats.input_vertices,
        input_triangles: scene.stats.input_triangles,
        welded_vertices: scene.stats.welded_vertices,
        degenerate_triangles_dropped: scene.stats.degenerate_triangles_dropped,
        nodes: tree.node_count(),
        depth: tree.max_depth(),
        degree_histogram: tree.degree_histogram(),
        seconds: Phases {
            import: import_seconds,
            cluster: timings.cluster.as_secs_f64(),
            adjacency: timings.adjacency.as_secs_f64(),
            attributes: timings.attributes.as_secs_f64(),
            subtris: timings.subtris.as_secs_f64(),
            total,
        },
        triangles_per_second: scene.stats.input_triangles as f64 / total,
        peak_rss_bytes: peak_rss_bytes(),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else if !args.quiet {
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
            if args.verify {
                ", all invariants hold"
            } else {
                ""
            }
        );
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
    Ok(())
}
