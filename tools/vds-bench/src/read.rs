//! `vds-bench read`: how fast the importers read, and the bunny as a whole `vds-build`
//! process against reading it and making one meshoptimizer LOD.
//!
//! Each file is read into a soup (`vds_import::read_file`: parse and check, no weld) as many
//! times as `--runs` asks; the median is reported as MB/s of the file as stored and as
//! triangles per second. The whole-process comparison runs the `vds-build` binary beside
//! this one (`vds-build bunny.obj -o FILE.vdt`, read, weld, tree, compressed file written)
//! against, in this process, the same OBJ read by the same reader and one `meshopt::simplify`
//! to 5,000 triangles: what one LOD of the peer costs from the same file.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};

use crate::median;

/// Prints the read speed of each file.
pub fn speeds(files: &[std::path::PathBuf], runs: usize) -> Result<()> {
    println!(
        "{:<48} {:>10} {:>12} {:>10} {:>12}",
        "file", "MB", "triangles", "ms", "MB/s"
    );
    for file in files {
        let bytes = std::fs::metadata(file)
            .with_context(|| format!("{}", file.display()))?
            .len();
        let mut triangles = 0;
        let ms = median(
            (0..runs)
                .map(|_| {
                    let start = Instant::now();
                    let mut soup = vds_import::MeshSoup::default();
                    vds_import::read_file(file, &Default::default(), &mut soup)?;
                    let ms = start.elapsed().as_secs_f64() * 1e3;
                    triangles = soup.triangles.len();
                    Ok(ms)
                })
                .collect::<Result<Vec<f64>>>()?,
        );
        println!(
            "{:<48} {:>10.1} {:>12} {:>10.1} {:>12.0}   {:.1} M triangles/s",
            file.display(),
            bytes as f64 / 1e6,
            triangles,
            ms,
            bytes as f64 / 1e3 / ms,
            triangles as f64 / 1e3 / ms
        );
    }
    Ok(())
}

/// Prints the bunny's whole-process ratio (`vds-build` against read + one `simplify`).
pub fn whole_process(bunny: &Path, runs: usize) -> Result<()> {
    let exe = std::env::current_exe()?;
    let build = exe.with_file_name("vds-build");
    if !build.exists() {
        bail!(
            "{} is missing: `cargo build --release -p vds-build` first",
            build.display()
        );
    }
    let out = std::env::temp_dir().join(format!("vds-bench-bunny-{}.vdt", std::process::id()));
    let mut process = Vec::new();
    let mut peer = Vec::new();
    let mut peer_read = Vec::new();
    // Alternated, so that both see the same spells of the machine.
    for _ in 0..runs {
        let start = Instant::now();
        let status = Command::new(&build)
            .arg(bunny)
            .arg("-o")
            .arg(&out)
            .arg("--quiet")
            .status()?;
        if !status.success() {
            bail!("vds-build failed on {}", bunny.display());
        }
        process.push(start.elapsed().as_secs_f64() * 1e3);
        let start = Instant::now();
        let scene = vds_import::load_file(bunny, &Default::default())?;
        peer_read.push(start.elapsed().as_secs_f64() * 1e3);
        let indices: Vec<u32> = scene.triangles.iter().flatten().copied().collect();
        let adapter =
            meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&scene.positions), 12, 0)?;
        std::hint::black_box(meshopt::simplify(
            &indices,
            &adapter,
            5_000 * 3,
            1.0,
            meshopt::SimplifyOptions::empty(),
            None,
        ));
        peer.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let _ = std::fs::remove_file(&out);
    let (process, peer, peer_read) = (median(process), median(peer), median(peer_read));
    println!(
        "bunny: `vds-build bunny.obj -o x.vdt` as a process {process:.1} ms; read + one meshopt \
         simplify → 5,000 in process {peer:.1} ms (of which read and weld {peer_read:.1} ms); \
         ratio {:.2}× (medians of {runs}, alternated)",
        process / peer
    );
    Ok(())
}
