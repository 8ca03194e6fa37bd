//! `vds-gen`: writes a deterministic CAD-like scene of about N triangles as binary PLY, as
//! Wavefront OBJ when the output's name ends in `.obj`, or as binary STL when it ends in
//! `.stl`. Each is written one machine cell at a time, so memory stays flat whatever the size.
//!
//! Exit codes: 0 success, 1 the file could not be written, 2 bad command line (a count that
//! is not a finite number from 1 to 1000M).

use std::io::BufWriter;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;

#[derive(Parser)]
#[command(
    about = "Generate a deterministic CAD-like scene as binary PLY (OBJ for a .obj output, binary STL for .stl), in flat memory"
)]
struct Args {
    /// Approximate triangle count, from 1 to 1000M (suffixes k and M accepted: 1M, 250k).
    #[arg(long, short, default_value = "1M", value_parser = parse_count)]
    triangles: u64,
    /// Output file: `.obj` writes Wavefront OBJ, `.stl` binary STL (one part, no shared
    /// vertices), anything else binary PLY.
    #[arg(long, short)]
    out: PathBuf,
}

/// The largest count `--triangles` accepts: a billion triangles make a 17 GB PLY file, beyond
/// any benchmark here; a larger count is a typo, and one past `u64` (`1e30`) would generate
/// until the disk is full.
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
    let extension_is = |name: &str| {
        args.out
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case(name))
    };
    let (obj, stl) = (extension_is("obj"), extension_is("stl"));
    // Write beside the target and rename, so an interrupted run leaves no partial file.
    let mut temporary = args.out.clone().into_os_string();
    temporary.push(".partial");
    let temporary = PathBuf::from(temporary);
    let totals = {
        let file = std::fs::File::create(&temporary)
            .with_context(|| format!("cannot create {}", temporary.display()))?;
        let mut out = BufWriter::new(file);
        let totals = if obj {
            vds_gen::write_obj(args.triangles, &mut out)
        } else if stl {
            vds_gen::write_stl(args.triangles, &mut out)
        } else {
            vds_gen::write_ply_streamed(args.triangles, &mut out)
        };
        let totals = totals.with_context(|| format!("cannot write {}", temporary.display()))?;
        std::io::Write::flush(&mut out)?;
        totals
    };
    std::fs::rename(&temporary, &args.out)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    if stl {
        eprintln!(
            "{}: {} triangles (STL: one part; the PLY form has {} vertices)",
            args.out.display(),
            totals.triangles,
            totals.vertices
        );
    } else {
        eprintln!(
            "{}: {} vertices, {} triangles, {} parts",
            args.out.display(),
            totals.vertices,
            totals.triangles,
            totals.parts
        );
    }
    Ok(())
}
