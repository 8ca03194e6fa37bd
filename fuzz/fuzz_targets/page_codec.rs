//! Fuzzes the page decoder directly, without the zstd frame and checksum in front of it:
//! any input must give an error or records that pass the reader's record checks, never a
//! panic, overflow, hang or huge allocation.
//!
//! Input: 28 bytes of page shape and file limits, then raw page streams (see
//! `vds_format::fuzzing::decode_page_and_check`). Seed the corpus with real pages:
//! `cargo run -p vds-format --features fuzzing --example page_seeds -- model.vdt fuzz/corpus/page_codec`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    vds_format::fuzzing::decode_page_and_check(data);
});
