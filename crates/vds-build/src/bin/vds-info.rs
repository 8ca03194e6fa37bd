//! `vds-info`: what is inside a `.vdt` file; `--verify` decodes every page, checks every
//! checksum, every figure of the header and metadata against the pages, and every
//! vertex-tree invariant; `--parts` prints the assembly as an indented tree. `--json` lists
//! every part (name, path, colour, parent, triangles) in `part_list`.
//!
//! Per-part triangle counts are the ones the file's metadata states (`vds-build` counts
//! them when it writes the file, and `--verify` holds them to the pages); a file that states
//! none has them counted from its pages here.
//!
//! Exit codes: 0 the file opened (and, with `--verify`, is intact), 1 it is not, 2 bad
//! command line.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Parser;
use serde::Serialize;

#[derive(Parser)]
#[command(version, about = "Describe (and verify) a .vdt vertex-tree file")]
struct Args {
    /// The .vdt file.
    file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Decode every page and check every checksum, header and metadata figure, and tree
    /// invariant.
    #[arg(long)]
    verify: bool,
    /// Print the parts as an indented tree (with `--json`: no effect, `part_list` has them).
    #[arg(long)]
    parts: bool,
}

/// One part, as `--json` lists it.
#[derive(Serialize)]
struct PartEntry {
    /// Its index: triangles name it by this id.
    index: usize,
    name: String,
    /// The names from the top of the assembly down to it, joined by `/`.
    path: String,
    /// RGBA in 0..1, or null.
    color: Option<[f32; 4]>,
    /// The index of its parent part, or null at the top.
    parent: Option<u32>,
    triangles: u64,
}

#[derive(Serialize)]
struct Info {
    file: String,
    version: u32,
    file_bytes: u64,
    vertices: u64,
    triangles: u64,
    input_triangles: u64,
    nodes: u64,
    depth: u32,
    degree_histogram: [u64; 9],
    parts: usize,
    part_list: Vec<PartEntry>,
    pages: u32,
    page_compressed_bytes: PageSizes,
    raw_page_bytes: u64,
    compressed_page_bytes: u64,
    bytes_per_input_triangle: f64,
    tool: String,
    zstd_level: i32,
    weld: Option<f32>,
    inputs: Vec<String>,
    open_ms: f64,
    verified: bool,
}

#[derive(Serialize)]
struct PageSizes {
    min: u32,
    median: u32,
    max: u32,
}

fn main() {
    let args = Args::parse();
    if let Err(error) = run(&args) {
        eprintln!("vds-info: {}: {error:#}", args.file.display());
        std::process::exit(1);
    }
}

fn run(args: &Args) -> Result<()> {
    let start = Instant::now();
    let file = vds_format::VdtFile::open(&args.file)?;
    let open_ms = start.elapsed().as_secs_f64() * 1e3;
    let header = file.header();
    let metadata = file.metadata();
    if args.verify {
        // Before anything is printed: a file that lies about its figures must not show them.
        vds_build::verify_file(&file)?;
    }
    let mut sizes: Vec<u32> = file
        .directory()
        .iter()
        .map(|p| p.compressed_length.get())
        .collect();
    sizes.sort_unstable();
    let raw: u64 = file
        .directory()
        .iter()
        .map(|p| u64::from(p.raw_length.get()))
        .sum();
    let compressed: u64 = sizes.iter().map(|&s| u64::from(s)).sum();
    let part_triangles: Vec<u64> = if metadata.parts.is_empty() && !metadata.part_names.is_empty() {
        let figures = vds_format::TreeFigures::of_file(&file)?;
        (0..metadata.part_names.len())
            .map(|i| figures.part_triangles.get(i).copied().unwrap_or(0))
            .collect()
    } else {
        metadata.parts.iter().map(|p| p.triangles).collect()
    };
    let part_list: Vec<PartEntry> = (0..metadata.part_names.len())
        .map(|i| PartEntry {
            index: i,
            name: metadata.part_names[i].clone(),
            path: metadata.part_path(i),
            color: metadata.part_color(i),
            parent: metadata.part_parent(i),
            triangles: part_triangles[i],
        })
        .collect();
    let info = Info {
        file: args.file.display().to_string(),
        version: header.version.get(),
        file_bytes: header.file_size.get(),
        vertices: header.vertex_count.get(),
        triangles: header.triangle_count.get(),
        input_triangles: metadata.input_triangles,
        nodes: header.node_count.get(),
        depth: header.max_depth.get(),
        degree_histogram: metadata.degree_histogram,
        parts: metadata.part_names.len(),
        part_list,
        pages: header.page_count.get(),
        page_compressed_bytes: PageSizes {
            min: sizes[0],
            median: sizes[sizes.len() / 2],
            max: sizes[sizes.len() - 1],
        },
        raw_page_bytes: raw,
        compressed_page_bytes: compressed,
        bytes_per_input_triangle: header.file_size.get() as f64
            / metadata.input_triangles.max(1) as f64,
        tool: metadata.tool.clone(),
        zstd_level: metadata.build.zstd_level,
        weld: metadata.build.weld,
        inputs: metadata
            .inputs
            .iter()
            .map(|i| {
                format!(
                    "{} ({} bytes, xxh3 {:016x})",
                    i.name, i.bytes, i.content_hash
                )
            })
            .collect(),
        open_ms,
        verified: args.verify,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
        return Ok(());
    }
    println!(
        "{}: .vdt version {}, {} bytes, written by {}",
        info.file, info.version, info.file_bytes, info.tool
    );
    println!(
        "  {} vertices, {} triangles ({} input), {} parts",
        info.vertices, info.triangles, info.input_triangles, info.parts
    );
    println!(
        "  {} nodes, depth {}, degrees {:?}",
        info.nodes, info.depth, info.degree_histogram
    );
    println!(
        "  {} pages: compressed {} B min / {} median / {} max; {} raw -> {} compressed bytes ({:.2}x)",
        info.pages,
        info.page_compressed_bytes.min,
        info.page_compressed_bytes.median,
        info.page_compressed_bytes.max,
        info.raw_page_bytes,
        info.compressed_page_bytes,
        info.raw_page_bytes as f64 / info.compressed_page_bytes.max(1) as f64
    );
    println!(
        "  {:.2} bytes per input triangle, all levels included",
        info.bytes_per_input_triangle
    );
    println!(
        "  built with zstd level {}, weld {:?}",
        info.zstd_level, info.weld
    );
    for input in &info.inputs {
        println!("  input: {input}");
    }
    println!("  opened in {:.2} ms", info.open_ms);
    if args.verify {
        println!(
            "  verified: every page checksum, every stated figure and every tree invariant holds"
        );
    }
    if args.parts {
        print_part_tree(&info.part_list);
    }
    Ok(())
}

/// Prints the parts as a tree, children indented two spaces under their parent, in index
/// order among siblings: `name  (N triangles, colour #rrggbbaa)`.
fn print_part_tree(parts: &[PartEntry]) {
    println!("parts:");
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); parts.len()];
    let mut roots = Vec::new();
    for part in parts {
        match part.parent {
            // Parents precede their children (the reader checks it), so this is a forest.
            Some(p) => children[p as usize].push(part.index),
            None => roots.push(part.index),
        }
    }
    // Depth first, without recursion (a hostile file may nest its parts deeply).
    let mut stack: Vec<(usize, usize)> = roots.iter().rev().map(|&r| (r, 1)).collect();
    while let Some((index, depth)) = stack.pop() {
        let part = &parts[index];
        let color = match part.color {
            Some(c) => {
                let byte = |v: f32| (v * 255.0).round() as u8;
                format!(
                    ", colour #{:02x}{:02x}{:02x}{:02x}",
                    byte(c[0]),
                    byte(c[1]),
                    byte(c[2]),
                    byte(c[3])
                )
            }
            None => String::new(),
        };
        println!(
            "{:indent$}{}  ({} triangles{color})",
            "",
            part.name,
            part.triangles,
            indent = 2 * depth
        );
        stack.extend(children[index].iter().rev().map(|&c| (c, depth + 1)));
    }
}
