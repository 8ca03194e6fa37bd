//! The `.vdt` file: build → write → read round trips keep every invariant, output is
//! byte-identical whatever the thread count, writes are atomic, and hostile files (bit flips,
//! truncation, spliced sections, huge counts with valid checksums) yield errors, never panics.

use std::path::PathBuf;

use proptest::prelude::*;
use vds_build::{
    VerifyError, build_tree, snap_to_grid, tree_content, tree_from_file, verify_file, verify_tree,
};
use vds_format::{StatedField, VdtError, VdtFile, WriteOptions, encode, write_file};
use xxhash_rust::xxh3::xxh3_64;

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

fn encoded(name: &str, options: &WriteOptions) -> Vec<u8> {
    let mut scene = vds_import::load_file(shared(name), &Default::default()).unwrap();
    let grid = snap_to_grid(&mut scene);
    let tree = build_tree(&scene);
    let metadata = vds_format::Metadata {
        tool: "test".into(),
        part_names: scene.part_names.clone(),
        parts: vds_build::part_records(&scene),
        ..Default::default()
    };
    encode(&tree_content(&tree, &scene, metadata, grid), options)
        .unwrap()
        .0
}

/// Small pages, so even small meshes span many pages.
fn small_pages() -> WriteOptions {
    WriteOptions {
        zstd_level: 3,
        page_bytes: 4096,
    }
}

/// A triangle rotated, winding kept, so that its smallest corner comes first.
fn smallest_first(t: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| t[k]).unwrap();
    [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
}

#[test]
fn round_trip_keeps_every_invariant_and_triangle() {
    for name in ["cow.obj", "as1_assembly.obj", "bone.ply"] {
        let mut scene = vds_import::load_file(shared(name), &Default::default()).unwrap();
        let grid = snap_to_grid(&mut scene);
        let tree = build_tree(&scene);
        let content = tree_content(
            &tree,
            &scene,
            vds_format::Metadata {
                part_names: scene.part_names.clone(),
                ..Default::default()
            },
            grid,
        );
        let (bytes, report) = encode(&content, &small_pages()).unwrap();
        assert!(report.pages > 3, "{name}: {} pages", report.pages);
        let file = VdtFile::from_bytes(bytes).unwrap();
        let (read_tree, read_scene) = tree_from_file(&file).unwrap();
        verify_tree(&read_tree, &read_scene).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(read_tree.nodes.len(), tree.nodes.len());
        // Same triangles (as original vertex ids, with parts, winding kept), in any order
        // and starting at any corner.
        let mut original: Vec<([u32; 3], u32)> = scene
            .triangles
            .iter()
            .zip(&scene.triangle_parts)
            .map(|(t, &p)| (smallest_first(*t), p))
            .collect();
        let mut read: Vec<([u32; 3], u32)> = read_scene
            .triangles
            .iter()
            .zip(&read_scene.triangle_parts)
            .map(|(t, &p)| {
                (
                    smallest_first(t.map(|rank| tree.leaf_vertex[rank as usize])),
                    p,
                )
            })
            .collect();
        original.sort_unstable();
        read.sort_unstable();
        assert_eq!(original, read, "{name}");
        // Leaves keep their exact original positions.
        for (rank, &v) in tree.leaf_vertex.iter().enumerate() {
            assert_eq!(read_scene.positions[rank], scene.positions[v as usize]);
        }
    }
}

#[test]
fn pages_hold_contiguous_nodes_and_root_page_is_small() {
    let file = VdtFile::from_bytes(encoded("bunny.obj", &WriteOptions::default())).unwrap();
    let directory = file.directory();
    assert!(directory[0].raw_length.get() <= vds_format::DEFAULT_PAGE_BYTES / 4 + 1024);
    for id in [0u32, 1, 500, 40_000] {
        let page = file.page_of_node(id).unwrap();
        let decoded = file.read_page(page).unwrap();
        assert!(decoded.node(id).is_some(), "node {id} not in page {page}");
    }
    assert!(file.page_of_node(u32::MAX).is_err());
}

/// The region of a node laid out in the top of the file.
const TOP: u32 = u32::MAX;

/// A decoded page and each of its nodes' regions.
type PageWithRegions = (vds_format::Page, Vec<u32>);

/// The bunny's file with pages of `page_bytes`, each page decoded with its nodes' regions:
/// the region root's id, or [`TOP`] for the top's nodes (parents come before children, so one
/// pass in page order finds them).
fn pages_with_regions(page_bytes: u32) -> (VdtFile<Vec<u8>>, Vec<PageWithRegions>) {
    let options = WriteOptions {
        zstd_level: 3,
        page_bytes,
    };
    let file = VdtFile::from_bytes(encoded("bunny.obj", &options)).unwrap();
    let limit = vds_format::region_leaves(page_bytes);
    let mut region: Vec<u32> = Vec::new();
    let mut leaves: Vec<u32> = Vec::new();
    let mut pages = Vec::new();
    for index in 0..file.directory().len() as u32 {
        let page = file.read_page(index).unwrap();
        let mut regions = Vec::with_capacity(page.nodes.len());
        for n in &page.nodes {
            let parent = n.parent.get();
            let r = if parent == u32::MAX || leaves[parent as usize] > limit {
                TOP
            } else if region[parent as usize] == TOP {
                parent
            } else {
                region[parent as usize]
            };
            region.push(r);
            leaves.push(n.leaf_end.get() - n.leaf_begin.get());
            regions.push(r);
        }
        pages.push((page, regions));
    }
    (file, pages)
}

/// The file is laid out in regions: top pages first, holding the nodes with more than a
/// region's leaves and their children, then each region root's subtree in leaf order, no page
/// mixing two regions (what lets the sharded merge encode one region at a time).
#[test]
fn pages_never_mix_regions_and_regions_follow_the_top_in_leaf_order() {
    for page_bytes in [4096, 1024] {
        let (file, pages) = pages_with_regions(page_bytes);
        let mut last_region_start = None;
        let mut regions_seen = 0;
        for (index, (page, regions)) in pages.iter().enumerate() {
            let in_page: std::collections::BTreeSet<u32> = regions.iter().copied().collect();
            assert_eq!(in_page.len(), 1, "page {index} mixes regions {in_page:?}");
            let r = *in_page.first().unwrap();
            if r == TOP {
                assert_eq!(regions_seen, 0, "a top page after a region's");
            } else if last_region_start != Some(r) {
                regions_seen += 1;
                let root = page.nodes[0].leaf_begin.get();
                // Leaf order: each region starts past where the previous one did.
                assert!(last_region_start.is_none_or(|p| root > leaf_begin_of(&file, p)));
                last_region_start = Some(r);
            }
        }
        assert!(
            regions_seen > 10,
            "{page_bytes} B pages: {regions_seen} regions"
        );
    }
}

/// Within the top and within each region, nodes follow breadth-first: depth never decreases
/// along the ids, and each level is in leaf order. So below a region's first pages a page
/// holds a slice of one or two levels, not a treelet reaching far below a boundary that
/// passes through it (what lets a memory budget hold a fine cut; `docs/benchmarks.md`, "Page
/// shape under a budget").
#[test]
fn nodes_run_breadth_first_within_the_top_and_each_region() {
    for page_bytes in [vds_format::DEFAULT_PAGE_BYTES, 4096, 1024] {
        let (_, pages) = pages_with_regions(page_bytes);
        // Per region, the (depth, first leaf) of its last node so far.
        let mut last = std::collections::HashMap::new();
        for (index, (page, regions)) in pages.iter().enumerate() {
            for (n, &r) in page.nodes.iter().zip(regions) {
                let key = (n.depth.get(), n.leaf_begin.get());
                if let Some(before) = last.insert(r, key) {
                    assert!(
                        before < key,
                        "{page_bytes} B pages, page {index}: (depth, first leaf) {key:?} after {before:?}"
                    );
                }
            }
        }
    }
}

fn leaf_begin_of(file: &VdtFile<Vec<u8>>, id: u32) -> u32 {
    let page = file.page_of_node(id).unwrap();
    file.read_page(page)
        .unwrap()
        .node(id)
        .unwrap()
        .leaf_begin
        .get()
}

#[test]
fn output_is_byte_identical_on_one_and_two_threads() {
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| encoded("cow.obj", &small_pages()))
    };
    assert!(on(1) == on(2));
}

/// The same input gives the same bytes on every machine, not only on every thread count: the
/// digests below were recorded on the dev machine, and CI checks them on its own. Nothing in
/// the build may depend on the CPU (the wide kernels compute what the baseline ones do; angles
/// come from the `libm` crate, not the system library, which picks code by CPU). A deliberate
/// change to the builder or the format changes these digests: print the new ones with
/// `cargo test -p vds-build --test vdt -- --nocapture digests` and update them here.
#[test]
fn output_digests_are_the_same_on_every_machine() {
    let mut differ = Vec::new();
    for (name, expected) in [
        ("bunny.obj", 0x10fceca4663834ffu64),
        ("as1_assembly.obj", 0x42e8209467454981),
        ("bone.ply", 0xcf13de843a171814),
    ] {
        let digest = xxh3_64(&encoded(name, &WriteOptions::default()));
        println!("digests: {name} {digest:#018x}");
        if digest != expected {
            differ.push(format!("{name}: {digest:#018x}, expected {expected:#018x}"));
        }
    }
    assert!(differ.is_empty(), "{differ:?}");
}

#[test]
fn write_is_atomic_and_leaves_no_partial_file() {
    let dir = std::env::temp_dir().join(format!("vds-vdt-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut scene = vds_import::load_file(shared("cow.obj"), &Default::default()).unwrap();
    let grid = snap_to_grid(&mut scene);
    let tree = build_tree(&scene);
    let content = tree_content(&tree, &scene, Default::default(), grid);
    let target = dir.join("cow.vdt");
    std::fs::write(&target, b"an older file").unwrap();
    write_file(&target, &content, &small_pages()).unwrap();
    assert!(
        VdtFile::open(&target).is_ok(),
        "the old file was replaced whole"
    );
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "leftovers: {names:?}");
    // A failed write (missing directory) leaves nothing behind.
    let missing = dir.join("no-such-dir").join("x.vdt");
    assert!(write_file(&missing, &content, &small_pages()).is_err());
    assert!(!missing.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn rejects_bad_magic() {
    let mut bytes = encoded("cow.obj", &small_pages());
    bytes[0] = b'X';
    assert!(matches!(VdtFile::from_bytes(bytes), Err(VdtError::Magic)));
}

#[test]
fn rejects_unknown_version_with_both_numbers() {
    for version in [1u32, 2, 3, vds_format::VDT_VERSION + 1] {
        let mut bytes = encoded("cow.obj", &small_pages());
        bytes[8..12].copy_from_slice(&version.to_le_bytes());
        fix_checksums(&mut bytes);
        match VdtFile::from_bytes(bytes) {
            Err(VdtError::Version { expected, got, .. })
                if expected == vds_format::VDT_VERSION && got == version => {}
            other => panic!("{:?}", other.err()),
        }
    }
}

/// The decoder's floats are finite only on a finite grid with a positive step: any other
/// grid is refused when the file opens.
#[test]
fn rejects_a_grid_that_could_decode_to_non_finite_floats() {
    let bytes = encoded("cow.obj", &small_pages());
    assert!(VdtFile::from_bytes(bytes.clone()).is_ok());
    // grid_origin at 104 (three f32), grid_step at 116.
    for (at, value) in [
        (116, 0.0f32),
        (116, -1.0),
        (116, f32::NAN),
        (116, f32::INFINITY),
        (116, 1e30),
        (104, f32::INFINITY),
        (108, f32::NAN),
        (112, f32::NEG_INFINITY),
    ] {
        let mut broken = bytes.clone();
        broken[at..at + 4].copy_from_slice(&value.to_le_bytes());
        fix_checksums(&mut broken);
        let error = VdtFile::from_bytes(broken).err();
        assert!(
            error
                .as_ref()
                .is_some_and(|e| e.to_string().contains("grid")),
            "{value} at {at}: {error:?}"
        );
    }
}

#[test]
fn rejects_truncated_file() {
    let bytes = encoded("cow.obj", &small_pages());
    let cut = bytes[..bytes.len() - 1].to_vec();
    assert!(VdtFile::from_bytes(cut).is_err());
}

#[test]
fn rejects_corrupted_page_by_checksum() {
    let mut bytes = encoded("cow.obj", &small_pages());
    let last = bytes.len() - 5;
    bytes[last] ^= 0x55;
    let file = VdtFile::from_bytes(bytes).unwrap();
    let last_page = file.directory().len() as u32 - 1;
    assert!(matches!(
        file.read_page(last_page),
        Err(VdtError::Checksum { .. })
    ));
    // The undecoded streams are checked the same way, and the intact pages' are as long as
    // the directory says.
    assert!(matches!(
        file.with_page_streams(last_page, |streams| streams.len()),
        Err(VdtError::Checksum { .. })
    ));
    for index in 0..last_page {
        let length = file
            .with_page_streams(index, |streams| streams.len())
            .unwrap();
        assert_eq!(
            length,
            file.directory()[index as usize].raw_length.get() as usize
        );
    }
}

/// Recomputes every checksum so mutations reach the validation behind them.
/// The reader reuses one zstd context, output buffer and decode scratch per thread, and a page
/// cache reuses its `Page`: whatever the order of reads, and after pages that failed to decode
/// (of another file), every page decodes exactly as on a thread that never read anything.
#[test]
fn reused_decode_buffers_give_the_pages_of_a_fresh_thread() {
    let bytes = encoded("cow.obj", &small_pages());
    let fresh: Vec<vds_format::Page> = std::thread::spawn({
        let bytes = bytes.clone();
        move || {
            VdtFile::from_bytes(bytes)
                .unwrap()
                .read_all_pages()
                .unwrap()
        }
    })
    .join()
    .unwrap();
    assert!(fresh.len() > 4);
    // A copy whose pages decode to garbage: every page's body flipped, checksums made valid.
    let mut broken = bytes.clone();
    let file = VdtFile::from_bytes(bytes).unwrap();
    for entry in file.directory() {
        let start = entry.offset.get() as usize;
        for b in &mut broken[start + 8..start + entry.compressed_length.get() as usize / 2] {
            *b ^= 0x5A;
        }
    }
    fix_checksums(&mut broken);
    let broken = VdtFile::from_bytes(broken).unwrap();
    let mut page = file.read_page(0).unwrap();
    let count = fresh.len() as u32;
    let mut failures = 0;
    for step in 0..3 * count {
        // Pages in a scrambled order, each read after a failed one.
        let index = (step * 7 + 3) % count;
        failures += usize::from(broken.read_page_into(count - 1 - index, &mut page).is_err());
        file.read_page_into(index, &mut page).unwrap();
        assert_eq!(page, fresh[index as usize], "page {index} at step {step}");
    }
    assert!(failures > 0, "the broken copy must fail somewhere");
}

fn fix_checksums(bytes: &mut [u8]) {
    let get = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let put = |b: &mut [u8], at: usize, v: u64| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
    if bytes.len() < 128 {
        return;
    }
    // Pages first: their checksums live in the directory, whose own checksum comes next.
    let (dir_offset, dir_length) = (get(bytes, 80) as usize, get(bytes, 88) as usize);
    for i in 0..dir_length / 40 {
        let Some(entry) = dir_offset
            .checked_add(40 * i)
            .filter(|e| e.saturating_add(40) <= bytes.len())
        else {
            break;
        };
        let offset = get(bytes, entry) as usize;
        let length = u32::from_le_bytes(bytes[entry + 8..entry + 12].try_into().unwrap()) as usize;
        if let Some(frame) = offset
            .checked_add(length)
            .and_then(|end| bytes.get(offset..end))
        {
            let sum = xxh3_64(frame);
            put(bytes, entry + 32, sum);
        }
    }
    // Sections: metadata at 56 (offset, length, checksum), directory at 80.
    for at in [56usize, 80] {
        let (offset, length) = (get(bytes, at) as usize, get(bytes, at + 8) as usize);
        if let Some(section) = offset
            .checked_add(length)
            .and_then(|end| bytes.get(offset..end))
        {
            let sum = xxh3_64(section);
            put(bytes, at + 16, sum);
        }
    }
    let sum = xxh3_64(&bytes[..120]);
    put(bytes, 120, sum);
}

/// Opening, decoding every page, rebuilding the tree and checking it: must not panic. Every
/// page that decodes must pass the reader's stand-alone record checks, which the decoder
/// promises to have made as it went.
fn exercise(bytes: Vec<u8>) {
    let Ok(file) = VdtFile::from_bytes(bytes) else {
        return;
    };
    for index in 0..file.directory().len() as u32 {
        if let Ok(page) = file.read_page(index) {
            assert!(
                file.validate_page(&page).is_ok(),
                "page {index} decoded but fails validation: {:?}",
                file.validate_page(&page)
            );
        }
    }
    if let Ok((tree, scene)) = tree_from_file(&file) {
        let _ = verify_tree(&tree, &scene);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn mutated_files_give_errors_not_panics(
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
        fix in any::<bool>(),
    ) {
        let mut bytes = encoded("cow.obj", &small_pages());
        for (at, value) in flips {
            let i = at.index(bytes.len());
            bytes[i] ^= value.max(1);
        }
        if truncate {
            bytes.truncate(cut.index(bytes.len() + 1));
        }
        if fix {
            fix_checksums(&mut bytes);
        }
        exercise(bytes);
    }

    /// Header fields overwritten with huge or random values, checksums made valid.
    #[test]
    fn huge_counts_and_spliced_sections_give_errors(
        field in prop::sample::select(vec![16usize, 24, 32, 40, 48, 52, 56, 64, 80, 88]),
        value in prop_oneof![Just(u64::MAX), Just(u64::from(u32::MAX)), any::<u64>(), 0u64..4096],
    ) {
        let mut bytes = encoded("cow.obj", &small_pages());
        bytes[field..field + 8].copy_from_slice(&value.to_le_bytes());
        fix_checksums(&mut bytes);
        exercise(bytes);
    }

    /// Directory entries rewritten (page offsets, lengths, counts), checksums made valid.
    #[test]
    fn rewritten_directory_entries_give_errors(
        page in any::<prop::sample::Index>(),
        field in prop::sample::select(vec![0usize, 8, 12, 16, 20, 24, 28]),
        value in prop_oneof![Just(u32::MAX), any::<u32>(), 0u32..64],
    ) {
        let mut bytes = encoded("cow.obj", &small_pages());
        let dir_offset = u64::from_le_bytes(bytes[80..88].try_into().unwrap()) as usize;
        let pages = u32::from_le_bytes(bytes[48..52].try_into().unwrap()) as usize;
        let at = dir_offset + 40 * page.index(pages) + field;
        bytes[at..at + 4].copy_from_slice(&value.to_le_bytes());
        fix_checksums(&mut bytes);
        exercise(bytes);
    }

    /// Raw page streams mutated and handed to the decoder directly (no zstd frame or
    /// checksum in front): an error, or records that pass the reader's record checks.
    #[test]
    fn mutated_raw_pages_give_errors_or_checked_records(
        page in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
    ) {
        let file = VdtFile::from_bytes(encoded("cow.obj", &small_pages())).unwrap();
        let index = page.index(file.directory().len()) as u32;
        let mut input = vds_format::fuzzing::page_input(&file, index).unwrap();
        // Unmutated, the page decodes: the harness hands the decoder what the reader does.
        prop_assert!(vds_format::fuzzing::decode_page_and_check(&input));
        for (at, value) in flips {
            let i = 28 + at.index(input.len() - 28);
            input[i] ^= value.max(1);
        }
        vds_format::fuzzing::decode_page_and_check(&input);
    }

    /// Page contents replaced by valid zstd frames of mutated records.
    #[test]
    fn mutated_records_in_valid_frames_give_errors(
        page in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..4),
    ) {
        let bytes = encoded("cow.obj", &small_pages());
        let file = VdtFile::from_bytes(bytes.clone()).unwrap();
        let index = page.index(file.directory().len());
        let entry = file.directory()[index];
        let start = entry.offset.get() as usize;
        let frame = &bytes[start..start + entry.compressed_length.get() as usize];
        let mut raw = zstd::bulk::decompress(frame, entry.raw_length.get() as usize).unwrap();
        for (at, value) in flips {
            let i = at.index(raw.len());
            raw[i] ^= value.max(1);
        }
        let new_frame = zstd::bulk::compress(&raw, 1).unwrap();
        // Splice the new frame in at the end and point the entry at it.
        let mut out = bytes.clone();
        let new_offset = out.len() as u64;
        out.extend_from_slice(&new_frame);
        let dir_offset = u64::from_le_bytes(out[80..88].try_into().unwrap()) as usize;
        let at = dir_offset + 40 * index;
        out[at..at + 8].copy_from_slice(&new_offset.to_le_bytes());
        out[at + 8..at + 12].copy_from_slice(&(new_frame.len() as u32).to_le_bytes());
        let size = out.len() as u64;
        out[16..24].copy_from_slice(&size.to_le_bytes());
        fix_checksums(&mut out);
        exercise(out);
    }
}

/// A file of `name` with every figure of its metadata stated truly (the import's counts, the
/// tree's degree histogram), after `lie` has edited that metadata: the writer stores
/// metadata as given, so its output is the honest file with the field patched and every
/// checksum recomputed.
fn stated_file(name: &str, lie: impl FnOnce(&mut vds_format::Metadata)) -> Vec<u8> {
    let mut scene = vds_import::load_file(shared(name), &Default::default()).unwrap();
    let grid = snap_to_grid(&mut scene);
    let tree = build_tree(&scene);
    let mut metadata = vds_format::Metadata {
        tool: "test".into(),
        part_names: scene.part_names.clone(),
        input_vertices: scene.stats.input_vertices,
        input_triangles: scene.stats.input_triangles,
        degree_histogram: tree.degree_histogram(),
        ..Default::default()
    };
    lie(&mut metadata);
    encode(&tree_content(&tree, &scene, metadata, grid), &small_pages())
        .unwrap()
        .0
}

/// `verify_file`'s verdict on `bytes`, which must open.
fn verified(bytes: Vec<u8>) -> Result<(), VerifyError> {
    verify_file(&VdtFile::from_bytes(bytes).expect("the file opens"))
}

/// Asserts that `bytes` opens but fails verification naming `field` with both values.
fn refused_naming(bytes: Vec<u8>, field: StatedField, stated: u64, counted: u64) {
    match verified(bytes) {
        Err(VerifyError::File(
            ref e @ VdtError::Misstated {
                field: f,
                stated: s,
                counted: c,
            },
        )) if f == field && s == stated && c == counted => {
            let message = e.to_string();
            assert!(
                message.contains(&field.to_string())
                    && message.contains(&stated.to_string())
                    && message.contains(&counted.to_string()),
                "{message}"
            );
        }
        other => panic!("{field}: expected Misstated {stated} / {counted}, got {other:?}"),
    }
}

fn put_u32(bytes: &mut [u8], at: usize, value: u32) {
    bytes[at..at + 4].copy_from_slice(&value.to_le_bytes());
}

fn get_u64(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
}

#[test]
fn verify_file_accepts_a_file_whose_figures_are_true() {
    let bytes = stated_file("cow.obj", |_| {});
    let file = VdtFile::from_bytes(bytes.clone()).unwrap();
    let figures = vds_format::TreeFigures::of_file(&file).unwrap();
    assert_eq!(figures.nodes, file.header().node_count.get());
    assert_eq!(figures.degree_histogram, file.metadata().degree_histogram);
    verified(bytes).unwrap();
}

#[test]
fn verify_refuses_a_header_max_depth_deeper_than_the_tree() {
    let mut bytes = stated_file("cow.obj", |_| {});
    let depth = u32::from_le_bytes(bytes[52..56].try_into().unwrap());
    // Deeper than the tree, still below the node count (what opening checks).
    put_u32(&mut bytes, 52, depth + 5);
    fix_checksums(&mut bytes);
    refused_naming(
        bytes,
        StatedField::MaxDepth,
        u64::from(depth + 5),
        u64::from(depth),
    );
}

/// A shallower depth than the tree's is refused by the page decoder (a node deeper than the
/// header's), a deeper one only by counting: both fail.
#[test]
fn verify_refuses_a_header_max_depth_shallower_than_the_tree() {
    let mut bytes = stated_file("cow.obj", |_| {});
    let depth = u32::from_le_bytes(bytes[52..56].try_into().unwrap());
    put_u32(&mut bytes, 52, depth - 1);
    fix_checksums(&mut bytes);
    let error = verified(bytes).unwrap_err();
    assert!(error.to_string().contains("depth"), "{error}");
}

#[test]
fn verify_refuses_a_header_vertex_count_above_the_leaves() {
    let mut bytes = stated_file("cow.obj", |_| {});
    let vertices = get_u64(&bytes, 40);
    bytes[40..48].copy_from_slice(&(vertices + 1).to_le_bytes());
    fix_checksums(&mut bytes);
    refused_naming(bytes, StatedField::VertexCount, vertices + 1, vertices);
}

/// The node, triangle and page counts are held to the directory when the file opens, so a
/// false one never reaches the count of the pages.
#[test]
fn header_node_triangle_and_page_counts_are_refused_on_open() {
    let honest = stated_file("cow.obj", |_| {});
    for (at, width) in [(24usize, 8usize), (32, 8), (48, 4)] {
        let mut bytes = honest.clone();
        let value = if width == 8 {
            get_u64(&bytes, at)
        } else {
            u64::from(u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()))
        };
        bytes[at..at + width].copy_from_slice(&(value - 1).to_le_bytes()[..width]);
        fix_checksums(&mut bytes);
        assert!(
            VdtFile::from_bytes(bytes).is_err(),
            "header field at {at} lowered by one was accepted"
        );
    }
}

#[test]
fn verify_refuses_every_false_degree_histogram_entry() {
    for k in 0..9u8 {
        let mut truth = 0;
        let bytes = stated_file("cow.obj", |m| {
            truth = m.degree_histogram[k as usize];
            m.degree_histogram[k as usize] += 7;
        });
        refused_naming(bytes, StatedField::DegreeHistogram(k), truth + 7, truth);
    }
}

/// Nodes moved from one degree to another keep the histogram's total: still refused.
#[test]
fn verify_refuses_a_degree_histogram_with_the_right_total() {
    let mut truth = [0; 9];
    let bytes = stated_file("cow.obj", |m| {
        truth = m.degree_histogram;
        m.degree_histogram[2] -= 3;
        m.degree_histogram[8] += 3;
    });
    refused_naming(
        bytes,
        StatedField::DegreeHistogram(2),
        truth[2] - 3,
        truth[2],
    );
}

#[test]
fn verify_refuses_input_triangles_fewer_than_the_tree_holds() {
    let bytes = stated_file("cow.obj", |m| m.input_triangles = 12);
    let triangles = get_u64(&bytes, 32);
    refused_naming(bytes, StatedField::InputTriangles, 12, triangles);
}

#[test]
fn verify_refuses_input_vertices_fewer_than_the_leaves() {
    let bytes = stated_file("cow.obj", |m| m.input_vertices = 3);
    let leaves = get_u64(&bytes, 40);
    refused_naming(bytes, StatedField::InputVertices, 3, leaves);
}

/// The decoder makes half-angles at most π; the stand-alone record check holds pages from
/// elsewhere to the same.
#[test]
fn validate_page_refuses_a_cone_wider_than_a_sphere() {
    let file = VdtFile::from_bytes(encoded("cow.obj", &small_pages())).unwrap();
    let mut page = file.read_page(0).unwrap();
    file.validate_page(&page).unwrap();
    let inner = page.nodes.iter().position(|n| n.child_count > 0).unwrap();
    page.nodes[inner].cone[3] = vds_format::layout::F32::new(3.2);
    let error = file.validate_page(&page).unwrap_err();
    assert!(error.to_string().contains("half-angle"), "{error}");
}
