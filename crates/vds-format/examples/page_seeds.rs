//! Writes seed inputs for the `page_codec` fuzz target from a `.vdt` file: each page's
//! shape and file limits (28 bytes, see `vds_format::fuzzing`) followed by its decompressed
//! streams.
//!
//! `cargo run -p vds-format --features fuzzing --example page_seeds -- model.vdt fuzz/corpus/page_codec`

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args_os().skip(1);
    let (Some(input), Some(out)) = (args.next(), args.next()) else {
        return Err("usage: page_seeds MODEL.vdt OUT_DIR".into());
    };
    let bytes = std::fs::read(&input)?;
    let file = vds_format::VdtFile::from_bytes(bytes.as_slice())?;
    let stem = PathBuf::from(&input)
        .file_stem()
        .map_or("vdt".into(), |s| s.to_string_lossy().into_owned());
    let out = PathBuf::from(out);
    std::fs::create_dir_all(&out)?;
    for index in 0..file.directory().len() as u32 {
        let seed = vds_format::fuzzing::page_input(&file, index)?;
        std::fs::write(out.join(format!("{stem}-page-{index:05}")), seed)?;
    }
    println!("{} seeds in {}", file.directory().len(), out.display());
    Ok(())
}
