//! Fuzzes the STL (ASCII and binary) importer and the weld step after it: any input must give an error
//! or a scene that keeps `vds_import::Scene`'s invariants (see `import_common.rs`).
//!
//! Seed the corpus with small files of the format (`testdata/`, `../shared/data/`).
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "import_common.rs"]
mod import_common;

fuzz_target!(|data: &[u8]| {
    import_common::import(data, vds_import::Format::Stl);
});
