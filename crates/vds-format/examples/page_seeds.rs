//! Writes seed inputs for the `page_codec` fuzz target from a `.vdt` file: each page's
//! shape and file limits (28 bytes, see `vds_format::fuzzing`) followed by its decompressed
//! streams.
//!
//! `cargo run -p vds-format --example page_seeds -- model.vdt fuzz/corpus/page_codec`

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
    let header = file.header();
    let nodes = u32::try_from(header.node_count.get())?;
    let vertices = u32::try_from(header.vertex_count.get())?;
    let parts = u32::try_from(file.metadata().part_names.len())?;
    for (index, entry) in file.directory().iter().enumerate() {
        let start = usize::try_from(entry.offset.get())?;
        let frame = &bytes[start..start + entry.compressed_length.get() as usize];
        let raw = zstd::bulk::decompress(frame, entry.raw_length.get() as usize)?;
        let mut seed = Vec::with_capacity(28 + raw.len());
        for word in [
            entry.first_node.get(),
            entry.node_count.get(),
            entry.first_triangle.get(),
            entry.triangle_count.get(),
            nodes,
            vertices,
            parts,
        ] {
            seed.extend_from_slice(&word.to_le_bytes());
        }
        seed.extend_from_slice(&raw);
        std::fs::write(out.join(format!("{stem}-page-{index:05}")), seed)?;
    }
    println!("{} seeds in {}", file.directory().len(), out.display());
    Ok(())
}
