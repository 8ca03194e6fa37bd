//! `vds-gen`: writes a deterministic CAD-like scene of about N triangles as binary PLY.
//!
//! Exit codes: 0 success, 1 the file could not be written, 2 bad command line (a count that
//! is not a finite number from 1 to 1000M).

use std::io::BufWriter;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;

#[derive(Parser)]
#[command(about = "Generate a deterministic CAD-like scene as binary PLY")]
struct Args {
    /// Approximate triangle count, from 1 to 1000M (suffixes k and M accepted: 1M, 250k).
    #[arg(long, short, default_value = "1M", value_parser = parse_count)]
    triangles: u64,
    /// Output file (.ply).
    #[arg(long, short)]
    out: PathBuf,
}

/// The largest count `--triangles` accepts: a billion triangles hold 12 GB of indices alone
/// before positions and the PLY buffer, more than the largest benchmark (10 M) by far; a
/// larger count is a typo, and one past `u64` (`1e30`) would generate until memory runs out.
const MAX_TRIANGLES: f64 = 1e9;

fn parse_count(text: &str) -> Result<u64, String> {
    let (digits, scale) = match text.strip_suffix(['M', 'm']) {
        Some(d) => (d, 1_000_000.0),
        None => match text.strip_suffix(['k', 'K']) {
            Some(d) => (d, 1_000.0),
            None => (text, 1.0),
        },
    };
    let n = digits
        .parse::<f64>()
        .map_err(|e| format!("bad count '{text}': {e}"))?
        * scale;
    // NaN fails both comparisons, so it is refused too.
    if (1.0..=MAX_TRIANGLES).contains(&n) {
        Ok(n as u64)
    } else {
        Err(format!("expected a count from 1 to 1000M, got '{text}'"))
    }
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
