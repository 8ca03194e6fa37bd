//! `vds-gen`: writes a deterministic CAD-like scene of about N triangles as binary PLY.

use std::io::BufWriter;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;

#[derive(Parser)]
#[command(about = "Generate a deterministic CAD-like scene as binary PLY")]
struct Args {
    /// Approximate triangle count (suffixes k and M accepted: 1M, 250k).
    #[arg(long, short, default_value = "1M", value_parser = parse_count)]
    triangles: u64,
    /// Output file (.ply).
    #[arg(long, short)]
    out: PathBuf,
}

fn parse_count(text: &str) -> Result<u64, String> {
    let (digits, scale) = match text.strip_suffix(['M', 'm']) {
        Some(d) => (d, 1_000_000.0),
        None => match text.strip_suffix(['k', 'K']) {
            Some(d) => (d, 1_000.0),
            None => (text, 1.0),
        },
    };
    digits
        .parse::<f64>()
        .map(|n| (n * scale) as u64)
        .map_err(|e| format!("bad count '{text}': {e}"))
}

fn main() -> Result<()> {
    let args = Args::parse();
    let scene = vds_gen::generate(args.triangles);
    // Write beside the target and rename, so an interrupted run leaves no partial file.
    let temporary = args.out.with_extension("ply.partial");
    {
        let file = std::fs::File::create(&temporary)
            .with_context(|| format!("cannot create {}", temporary.display()))?;
        let mut out = BufWriter::new(file);
        vds_gen::write_ply(&scene, &mut out)
            .with_context(|| format!("cannot write {}", temporary.display()))?;
        std::io::Write::flush(&mut out)?;
    }
    std::fs::rename(&temporary, &args.out)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    eprintln!(
        "{}: {} vertices, {} triangles, {} parts",
        args.out.display(),
        scene.positions.len(),
        scene.triangles.len(),
        scene.part_count
    );
    Ok(())
}
