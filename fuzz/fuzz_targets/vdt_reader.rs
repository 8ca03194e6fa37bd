//! Fuzzes the `.vdt` reader: open, decode every page (each must pass `validate_page`), then
//! verify the file as `vds-info --verify` does (stated figures, rebuilt tree, invariants).
//! Any input must give an error or valid data, never a panic, hang or huge allocation.
//!
//! Seed the corpus with real files so the fuzzer starts past the magic and checksums:
//! `vds-build testdata/as1_assembly.obj -o fuzz/corpus/vdt_reader/as1.vdt`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(file) = vds_format::VdtFile::from_bytes(data) else {
        return;
    };
    // The decoder checks records as it goes: what it returns must pass the stand-alone checks.
    for index in 0..file.directory().len() as u32 {
        if let Ok(page) = file.read_page(index) {
            assert!(file.validate_page(&page).is_ok(), "page {index}");
        }
    }
    // Everything `vds-info --verify` checks: the figures the header and metadata state, the
    // rebuilt tree's invariants. Any verdict will do; a panic will not.
    let _ = vds_build::verify_file(&file);
});
