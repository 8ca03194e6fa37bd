//! The sharded build (plan, shards, merge) writes the same file as the in-memory build, byte
//! for byte, on real meshes, the bundled assembly, generated CAD scenes and soups made to hit
//! the octree's corner cases, for several shard counts; part files round-trip, and a merge
//! refuses a missing, duplicated, foreign, truncated or damaged part.

use std::path::PathBuf;

use vds_build::shard::{
    Durability, PartHead, Plan, PlanMetadata, RegionPage, ShardError, ShardPart, build_shard,
    merge, plan, read_part, read_part_checked, read_part_head, write_part,
};
use vds_build::{build_tree, part_records, snap_to_grid, tree_content};
use vds_format::{BuildInfo, Grid, Metadata, WriteOptions, encode};
use vds_import::Scene;

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

fn testdata(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../testdata")
        .join(name)
}

/// Small pages, so that the layout is tested across many pages.
const PAGE_BYTES: u32 = 8192;

/// Page sizes the files are compared at: the default of these tests, and pages so small that
/// regions (`vds_format::region_leaves`), and so the plan's roots, hold 64 and 2 leaves.
const PAGE_SIZES: [u32; 3] = [PAGE_BYTES, 256, 8];

fn options_with(page_bytes: u32) -> WriteOptions {
    WriteOptions {
        zstd_level: 3,
        page_bytes,
    }
}

fn loaded(path: PathBuf) -> (Scene, Grid) {
    let mut scene = vds_import::load_file(&path, &Default::default()).unwrap();
    let grid = snap_to_grid(&mut scene);
    (scene, grid)
}

fn snapped(mut scene: Scene) -> (Scene, Grid) {
    let grid = snap_to_grid(&mut scene);
    (scene, grid)
}

fn metadata_of(scene: &Scene, page_bytes: u32) -> PlanMetadata {
    PlanMetadata::of_scene(
        scene,
        "vds-build test".into(),
        &options_with(page_bytes),
        vec![("input.obj".into(), 1234, 0xfeed)],
    )
}

/// The file the in-memory build writes, with the metadata `vds-build` gives it.
fn in_memory(scene: &Scene, grid: Grid, page_bytes: u32) -> Vec<u8> {
    let m = metadata_of(scene, page_bytes);
    let tree = build_tree(scene);
    let (center, radius) = tree.sphere(0);
    let metadata = Metadata {
        tool: m.tool.clone(),
        build: BuildInfo {
            weld: None,
            zstd_level: m.zstd_level,
            page_bytes: m.page_bytes,
        },
        inputs: vec![vds_format::InputInfo {
            name: "input.obj".into(),
            bytes: 1234,
            content_hash: 0xfeed,
        }],
        part_names: scene.part_names.clone(),
        parts: part_records(scene),
        bounds_min: [0, 1, 2].map(|k| center[k] - radius),
        bounds_max: [0, 1, 2].map(|k| center[k] + radius),
        input_vertices: scene.stats.input_vertices,
        input_triangles: scene.stats.input_triangles,
        degree_histogram: tree.degree_histogram(),
    };
    encode(
        &tree_content(&tree, scene, metadata, grid),
        &options_with(page_bytes),
    )
    .unwrap()
    .0
}

fn planned(scene: &Scene, grid: Grid, shards: u32) -> Plan {
    planned_with(scene, grid, shards, PAGE_BYTES)
}

fn planned_with(scene: &Scene, grid: Grid, shards: u32, page_bytes: u32) -> Plan {
    plan(
        &scene.positions,
        scene.triangles.len() as u64,
        grid,
        shards,
        metadata_of(scene, page_bytes),
    )
    .unwrap()
}

fn parts(scene: &Scene, plan: &Plan) -> Vec<ShardPart> {
    (0..plan.shard_count())
        .map(|k| build_shard(scene, plan, k).unwrap())
        .collect()
}

/// The sharded build's file, its plan, and how many of the parts' region pages the shards
/// sealed (encoded as the file's pages) and left open (as records, for the merge to encode).
fn sharded(scene: &Scene, grid: Grid, shards: u32, page_bytes: u32) -> (Vec<u8>, Plan, [usize; 2]) {
    let plan = planned_with(scene, grid, shards, page_bytes);
    let mut parts = parts(scene, &plan);
    let mut kinds = [0, 0];
    let pages = parts
        .iter()
        .flat_map(|p| &p.roots)
        .flat_map(|r| &r.regions)
        .flat_map(|g| &g.pages);
    for page in pages {
        kinds[usize::from(matches!(page, RegionPage::Open(_)))] += 1;
    }
    // Any order will do.
    parts.reverse();
    let bytes = merge(&plan, parts).unwrap();
    (bytes, plan, kinds)
}

fn assert_same_file(name: &str, scene: &Scene, grid: Grid, shard_counts: &[u32]) {
    let mut kinds = [0, 0];
    for page_bytes in PAGE_SIZES {
        let expected = in_memory(scene, grid, page_bytes);
        for &shards in shard_counts {
            let (bytes, plan, regions) = sharded(scene, grid, shards, page_bytes);
            kinds = [kinds[0] + regions[0], kinds[1] + regions[1]];
            assert!(
                bytes == expected,
                "{name}, {page_bytes} B pages, {shards} shards ({} roots, {} top nodes): the \
                 file differs",
                plan.roots.len(),
                plan.top.len()
            );
            // The test means something only if the model was really cut up: with the
            // smallest pages (regions of two leaves) and with 256 B pages (regions of 64
            // leaves), on scenes of more than a few regions.
            let cut_up = page_bytes == PAGE_SIZES[2]
                || page_bytes == PAGE_SIZES[1] && scene.positions.len() > 1000;
            if shards > 1 && cut_up {
                assert!(
                    plan.roots.len() > 1,
                    "{name}, {page_bytes} B pages: one root"
                );
            }
        }
    }
    // Both kinds of page went through the merge, on scenes cut into many regions: pages the
    // shards encoded, and pages with triangles across shards that the merge encoded.
    assert!(
        scene.positions.len() < 1000 || kinds[0] > 0 && kinds[1] > 0,
        "{name}: sealed and open pages {kinds:?}"
    );
}

#[test]
fn sharded_builds_write_the_in_memory_file_on_real_meshes() {
    for name in ["cow.obj", "bunny.obj", "bone.ply", "airplane.obj"] {
        let (scene, grid) = loaded(shared(name));
        assert_same_file(name, &scene, grid, &[1, 2, 3, 8]);
    }
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    assert_same_file("as1_assembly.obj", &scene, grid, &[1, 2, 5, 16]);
}

#[test]
fn sharded_builds_write_the_in_memory_file_on_generated_scenes() {
    let generated = vds_gen::generate(150_000);
    let scene = Scene {
        positions: generated.positions,
        triangles: generated.triangles,
        triangle_parts: generated.triangle_parts,
        part_names: (0..generated.part_count)
            .map(|k| format!("part {k}"))
            .collect(),
        ..Default::default()
    };
    // Through the importer's weld, as a file would go.
    let mut soup = vds_import::MeshSoup::default();
    soup.positions = scene.positions;
    soup.triangles = scene.triangles;
    soup.triangle_parts = scene.triangle_parts;
    soup.part_names = scene.part_names;
    let (scene, grid) = snapped(vds_import::weld(soup, vds_import::Weld::Exact));
    assert_same_file("generated 150 k", &scene, grid, &[2, 4, 7, 32]);
}

/// Deterministic values in `[0, 1)`.
fn randoms(mut seed: u64) -> impl FnMut() -> f32 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 40) as f32 / (1u64 << 24) as f32
    }
}

#[test]
fn sharded_builds_write_the_in_memory_file_on_corner_cases() {
    // Unwelded coincident vertices in heaps (balanced-chunk splits at the top), a flat
    // plate, a far-away speck, long slivers whose corners lie far apart (triangles across
    // three roots), and vertices in many tiny clusters.
    let mut random = randoms(5);
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for i in 0..3000u32 {
        let p = match i % 6 {
            0 => [0.5, 0.5, 0.5],
            1 => [random(), random(), 0.0],
            2 => [random() * 1e-4 + 7.0, 7.0, 7.0],
            3 => [random(), random(), random()],
            4 => [0.25, 0.75, 0.25],
            _ => [(i % 17) as f32 * 0.01, (i % 13) as f32 * 0.01, 0.9],
        };
        positions.push(p);
    }
    let n = positions.len() as u32;
    for i in 0..n {
        let j = (i * 7 + 1) % n;
        let k = (i * 13 + 5) % n;
        if i != j && j != k && i != k {
            triangles.push([i, j, k]);
        }
    }
    let parts = triangles
        .iter()
        .enumerate()
        .map(|(t, _)| (t % 3) as u32)
        .collect();
    let scene = Scene {
        positions,
        triangles,
        triangle_parts: parts,
        part_names: vec!["a".into(), "b".into(), "c".into()],
        ..Default::default()
    };
    let (scene, grid) = snapped(scene);
    assert_same_file("corner cases", &scene, grid, &[1, 2, 3, 6, 50]);

    // One vertex per root at most: the plan splits down to single vertices.
    let scene = Scene {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 1.0],
        ],
        triangles: vec![[0, 1, 2], [1, 3, 2]],
        triangle_parts: vec![0, 0],
        part_names: vec!["x".into()],
        ..Default::default()
    };
    let (scene, grid) = snapped(scene);
    assert_same_file("four vertices", &scene, grid, &[1, 2, 4, 9]);
}

fn temp_dir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn parts_round_trip_through_files_and_the_plan_through_json() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned(&scene, grid, 3);
    let dir = temp_dir();
    let plan_path = dir.path().join("plan.json");
    plan.save(&plan_path).unwrap();
    assert_eq!(Plan::load(&plan_path).unwrap(), plan);
    let root_of = vds_build::shard::roots_of_vertices(&scene, &plan).unwrap();
    for part in parts(&scene, &plan) {
        let path = dir.path().join(format!("shard-{}.vdtpart", part.index));
        write_part(&path, &part).unwrap();
        assert_eq!(read_part(&path, &plan).unwrap(), part);
        // The head the merge's first pass reads, seeking over pages and leaves, is the one
        // a full read gives, stamped alike; a part's head made in memory is stamped apart.
        let head = read_part_head(&path, &plan).unwrap();
        assert_eq!(head, read_part_checked(&path, &plan).unwrap().head());
        assert_ne!(head, PartHead::of(&part));
        // Written root by root as the shard builds them: the same bytes.
        let streamed = dir.path().join("streamed.vdtpart");
        let input = vds_build::shard::shard_input_of(&scene, &plan, &root_of, part.index);
        vds_build::shard::write_shard(&streamed, &plan, part.index, input, Durability::Synced)
            .unwrap();
        assert_eq!(
            std::fs::read(&streamed).unwrap(),
            std::fs::read(&path).unwrap()
        );
    }
}

#[test]
fn an_edited_plan_is_refused() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned(&scene, grid, 3);
    let dir = temp_dir();
    let path = dir.path().join("plan.json");
    let mut edited = plan.clone();
    edited.vertices += 1;
    std::fs::write(&path, serde_json::to_vec(&edited).unwrap()).unwrap();
    let error = Plan::load(&path).unwrap_err();
    assert!(matches!(error, ShardError::BadPlan { .. }), "{error}");
    std::fs::write(&path, b"{\"format\": 1").unwrap();
    assert!(matches!(Plan::load(&path), Err(ShardError::BadPlan { .. })));
}

/// The merge reads each part's head, then the part; a part that changed in between (a file
/// rewritten while the merge ran) is refused rather than mixed into the file.
#[test]
fn merge_refuses_a_part_that_changes_between_its_passes() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned_with(&scene, grid, 2, 256);
    let all = parts(&scene, &plan);
    let result = vds_build::shard::merge_to(
        &plan,
        |k| Ok(PartHead::of(&all[k as usize])),
        |k| {
            let mut part = all[k as usize].clone();
            // Same shape, one proxy moved.
            let node = &mut part.roots[0].top_nodes[0];
            node.proxy[0] = (node.proxy[0].get() + 1.0).into();
            Ok(part.into())
        },
        &mut Vec::new(),
        &std::env::temp_dir(),
    );
    let error = result.unwrap_err().to_string();
    assert!(error.contains("changed between"), "{error}");
}

/// The assembly planned in two shards with small pages (regions of pages in each part), its
/// parts, and the parts written to files in a temporary folder.
fn assembly_part_files() -> (Plan, Vec<ShardPart>, tempfile::TempDir, Vec<PathBuf>) {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned_with(&scene, grid, 2, 256);
    let all = parts(&scene, &plan);
    let dir = temp_dir();
    let paths: Vec<PathBuf> = all
        .iter()
        .map(|part| {
            let path = dir.path().join(format!("shard-{}.vdtpart", part.index));
            write_part(&path, part).unwrap();
            path
        })
        .collect();
    (plan, all, dir, paths)
}

/// Parts read from files are told apart by their checksums, not hashed again: a part file
/// rewritten between the merge's passes (same plan, same shape) is refused, and one left as
/// it was merges into the in-memory merge's bytes.
#[test]
fn merge_refuses_a_part_file_rewritten_between_its_passes() {
    let (plan, all, _dir, paths) = assembly_part_files();
    let expected = merge(&plan, all.clone()).unwrap();
    for rewrite in [false, true] {
        let mut out = Vec::new();
        let result = vds_build::shard::merge_to(
            &plan,
            |k| read_part_head(&paths[k as usize], &plan),
            |k| {
                // After the first pass read every head, part 0 is written again.
                if rewrite && k == 0 {
                    let mut part = all[k as usize].clone();
                    let node = &mut part.roots[0].top_nodes[0];
                    node.proxy[0] = (node.proxy[0].get() + 1.0).into();
                    write_part(&paths[k as usize], &part).unwrap();
                }
                read_part_checked(&paths[k as usize], &plan)
            },
            &mut out,
            &std::env::temp_dir(),
        );
        if rewrite {
            let error = result.unwrap_err().to_string();
            assert!(error.contains("changed between"), "{error}");
        } else {
            result.unwrap();
            assert_eq!(out, expected);
        }
    }
}

#[test]
fn merge_refuses_a_missing_duplicated_or_foreign_part() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned(&scene, grid, 3);
    let all = parts(&scene, &plan);

    let missing = merge(&plan, all[..2].to_vec()).unwrap_err().to_string();
    assert!(missing.contains("shard 2 of 3 is missing"), "{missing}");
    let mut twice = all.clone();
    twice.push(all[1].clone());
    let duplicated = merge(&plan, twice).unwrap_err().to_string();
    assert!(
        duplicated.contains("shard 1 is given twice"),
        "{duplicated}"
    );

    let other = planned(&scene, grid, 4);
    let mut foreign = all.clone();
    foreign[0] = build_shard(&scene, &other, 0).unwrap();
    let error = merge(&plan, foreign.clone()).unwrap_err().to_string();
    assert!(error.contains("another plan"), "{error}");

    // As files: a foreign part names the plan it was built for.
    let dir = temp_dir();
    let path = dir.path().join("foreign.vdtpart");
    write_part(&path, &foreign[0]).unwrap();
    let error = read_part(&path, &plan).unwrap_err();
    assert!(
        matches!(&error, ShardError::BadFile { reason, .. } if reason.contains("another plan")),
        "{error}"
    );
}

#[test]
fn truncated_or_damaged_parts_are_refused() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned(&scene, grid, 2);
    let part = build_shard(&scene, &plan, 1).unwrap();
    let dir = temp_dir();
    let path = dir.path().join("shard-1.vdtpart");
    write_part(&path, &part).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let broken = dir.path().join("broken.vdtpart");
    let mut cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty", Vec::new()),
        ("header only", bytes[..48].to_vec()),
        ("half", bytes[..bytes.len() / 2].to_vec()),
        ("one byte short", bytes[..bytes.len() - 1].to_vec()),
    ];
    for at in [3, 20, 60, bytes.len() / 2, bytes.len() - 3] {
        let mut flipped = bytes.clone();
        flipped[at] ^= 0x10;
        cases.push(("a flipped bit", flipped));
    }
    for (what, data) in cases {
        std::fs::write(&broken, &data).unwrap();
        match read_part(&broken, &plan) {
            Err(ShardError::BadFile { path, .. }) => assert_eq!(path, broken, "{what}"),
            other => panic!("{what}: {other:?}"),
        }
        // Skimmed, a damaged page or leaf can pass unseen (the full read of the second pass
        // refuses it); anything else is refused, naming the file.
        if let Err(error) = read_part_head(&broken, &plan) {
            assert!(
                matches!(&error, ShardError::BadFile { path, .. } if *path == broken),
                "{what}: {error:?}"
            );
        }
    }
}

/// The merge's first pass reads a part file's heads unverified (it seeks over the rest): a
/// part damaged anywhere, in a head, a page or a leaf, is still never merged, as the second
/// pass reads it whole and checks it.
#[test]
fn a_part_file_damaged_anywhere_is_not_merged() {
    let (plan, _, _dir, paths) = assembly_part_files();
    let good = std::fs::read(&paths[1]).unwrap();
    let merge_files = || {
        vds_build::shard::merge_to(
            &plan,
            |k| read_part_head(&paths[k as usize], &plan),
            |k| read_part_checked(&paths[k as usize], &plan),
            &mut Vec::new(),
            &std::env::temp_dir(),
        )
    };
    merge_files().unwrap();
    // The body lies between the 32-byte header and the 24-byte trailer.
    let body = 32..good.len() - 24;
    for step in 1..=23 {
        let at = body.start + (body.end - body.start) * step / 24;
        let mut damaged = good.clone();
        damaged[at] ^= 0x04;
        std::fs::write(&paths[1], &damaged).unwrap();
        assert!(merge_files().is_err(), "a bit flipped at byte {at} merged");
    }
}

/// A part whose nodes all claim every triangle (a valid tree otherwise, and tiny once
/// compressed) is refused before the merge would copy the triangles once per node.
#[test]
fn a_part_with_overlapping_subtri_ranges_is_refused() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    // Pages so large that the whole tree is the file's top: every node is a record.
    let plan = planned_with(&scene, grid, 2, 1 << 20);
    let mut part = build_shard(&scene, &plan, 0).unwrap();
    let root = part
        .roots
        .iter_mut()
        .max_by_key(|r| r.top_triangles.len())
        .unwrap();
    let all = root.top_triangles.len() as u32;
    assert!(all > 0 && root.top_nodes.len() > 2);
    for n in &mut root.top_nodes {
        n.subtri_begin = 0.into();
        n.subtri_count = all.into();
    }
    let dir = temp_dir();
    let path = dir.path().join("overlapping.vdtpart");
    write_part(&path, &part).unwrap();
    match read_part(&path, &plan) {
        Err(ShardError::BadFile { reason, .. }) => {
            assert!(reason.contains("subtris"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_shard_refuses_an_input_that_is_not_the_plans() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    // Small pages: a plan of many roots, so that a moved vertex leaves its root's cell.
    let plan = planned_with(&scene, grid, 2, 256);
    let mut moved = scene.clone();
    moved.positions[10][0] += 1000.0;
    assert!(matches!(
        build_shard(&moved, &plan, 0),
        Err(ShardError::InputChanged(_))
    ));
    let mut fewer = scene.clone();
    fewer.triangles.pop();
    assert!(matches!(
        build_shard(&fewer, &plan, 0),
        Err(ShardError::InputChanged(_))
    ));
}

#[test]
fn shard_inputs_round_trip_through_files() {
    use vds_build::shard::{
        build_shard_from, read_shard_input, roots_of_vertices, shard_input_of,
        shard_triangle_counts, stamp_shard_inputs, write_shard_inputs,
    };
    let (scene, grid) = loaded(shared("cow.obj"));
    let mut plan = planned(&scene, grid, 3);
    let dir = temp_dir();
    let paths: Vec<PathBuf> = (0..3)
        .map(|k| dir.path().join(format!("shard-{k}.vdtin")))
        .collect();
    let root_of = roots_of_vertices(&scene, &plan).unwrap();
    // Without the shards' triangle counts in the plan, an input is not read.
    let written_for = plan.id;
    let transient = Durability::Transient;
    let counts =
        write_shard_inputs(&scene, &plan, &root_of, &paths, 2, transient, |_, _| {}).unwrap();
    assert!(matches!(
        read_shard_input(&paths[0], &plan, 0),
        Err(ShardError::BadFile { .. })
    ));
    // The writing counts each shard's triangles as the pass of its own does.
    assert_eq!(
        counts,
        shard_triangle_counts(&scene, &plan, &root_of).unwrap()
    );
    plan.shard_triangles = counts;
    plan.seal();
    // The inputs name the plan as it was when they were written, not the one sealed with
    // their counts, until they are stamped; a stamp for another shard's file, or for files
    // written for another plan, is refused.
    assert!(matches!(
        read_shard_input(&paths[0], &plan, 0),
        Err(ShardError::BadFile { reason, .. }) if reason.contains("not of shard 0 of this plan")
    ));
    assert!(matches!(
        stamp_shard_inputs(&paths[1..], written_for, &plan, transient),
        Err(ShardError::BadFile { reason, .. }) if reason.contains("not of shard 0")
    ));
    assert!(matches!(
        stamp_shard_inputs(&paths, written_for ^ 1, &plan, transient),
        Err(ShardError::BadFile { reason, .. }) if reason.contains("not of shard 0")
    ));
    stamp_shard_inputs(&paths, written_for, &plan, Durability::Synced).unwrap();
    for (k, path) in paths.iter().enumerate() {
        let input = read_shard_input(path, &plan, k as u32).unwrap();
        assert_eq!(input, shard_input_of(&scene, &plan, &root_of, k as u32));
        // A corner whose vertex is not listed, and a listed vertex no corner uses, are
        // refused.
        let mut short = input.clone();
        short.vertices.remove(short.vertices.len() / 2);
        assert!(matches!(
            build_shard_from(&plan, k as u32, short),
            Err(ShardError::InputChanged(reason)) if reason.contains("not listed")
        ));
        let mut long = input.clone();
        let unused = (0..plan.vertices)
            .find(|&v| {
                long.vertices
                    .binary_search_by_key(&v, |x| x.vertex.get())
                    .is_err()
            })
            .unwrap();
        let at = long.vertices.partition_point(|x| x.vertex.get() < unused);
        long.vertices
            .insert(at, vds_build::shard::input_vertex(unused, &scene.positions));
        assert!(matches!(
            build_shard_from(&plan, k as u32, long),
            Err(ShardError::InputChanged(reason)) if reason.contains("no triangle uses")
        ));
        let mut swapped = input.clone();
        swapped.vertices.swap(0, 1);
        assert!(matches!(
            build_shard_from(&plan, k as u32, swapped),
            Err(ShardError::InputChanged(reason)) if reason.contains("vertices out of order")
        ));
        // A corner naming a vertex the plan does not have is refused, not numbered.
        let mut past = input.clone();
        past.triangles[0].vertices[1] = plan.vertices.into();
        assert!(matches!(
            build_shard_from(&plan, k as u32, past),
            Err(ShardError::InputChanged(reason)) if reason.contains("a vertex past the plan's count")
        ));
        assert_eq!(
            build_shard_from(&plan, k as u32, input).unwrap(),
            build_shard(&scene, &plan, k as u32).unwrap()
        );
        // Another shard's input is refused, and so is a damaged one.
        let other = (k + 1) % 3;
        assert!(read_shard_input(path, &plan, other as u32).is_err());
        let mut bytes = std::fs::read(path).unwrap();
        // A byte of the body (past the 32-byte header), whose trailer is intact.
        let at = 32 + (bytes.len() - 32 - 24) / 2;
        bytes[at] ^= 0x40;
        let broken = dir.path().join("broken.vdtin");
        std::fs::write(&broken, &bytes).unwrap();
        assert!(matches!(
            read_shard_input(&broken, &plan, k as u32),
            Err(ShardError::BadFile { .. })
        ));
    }
}

/// Plans edited and then given a matching id (the id is a checksum, not a signature): each is
/// refused, or shards and merge run on it to an error or a file, never a panic.
#[test]
fn crafted_plans_never_panic_a_shard_or_merge() {
    let (scene, grid) = loaded(testdata("as1_assembly.obj"));
    let plan = planned(&scene, grid, 3);
    let original = serde_json::to_value(&plan).unwrap();
    // Every integer in the plan, as a path of keys and indices.
    fn integers(value: &serde_json::Value, path: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
        match value {
            serde_json::Value::Number(n) if n.is_u64() => out.push(path.clone()),
            serde_json::Value::Array(items) => {
                for (k, item) in items.iter().enumerate() {
                    path.push(k.to_string());
                    integers(item, path, out);
                    path.pop();
                }
            }
            serde_json::Value::Object(fields) => {
                for (key, item) in fields {
                    if key != "id" && key != "metadata" {
                        path.push(key.clone());
                        integers(item, path, out);
                        path.pop();
                    }
                }
            }
            _ => {}
        }
    }
    let mut paths = Vec::new();
    integers(&original, &mut Vec::new(), &mut paths);
    assert!(paths.len() > 100, "{} integers", paths.len());
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut random = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let mut accepted = 0;
    for round in 0..600 {
        let mut value = original.clone();
        let path = &paths[random() as usize % paths.len()];
        let mut slot = &mut value;
        for key in path {
            slot = match slot {
                serde_json::Value::Array(items) => &mut items[key.parse::<usize>().unwrap()],
                serde_json::Value::Object(fields) => fields.get_mut(key).unwrap(),
                _ => unreachable!(),
            };
        }
        let old = slot.as_u64().unwrap();
        let new = match round % 4 {
            0 => old + 1,
            1 => old.saturating_sub(1),
            2 => 0,
            _ => [u64::from(u32::MAX), 1 << 40, old * 2 + 7][round % 3],
        };
        *slot = serde_json::Value::from(new);
        let Ok(mut crafted) = serde_json::from_value::<Plan>(value) else {
            continue;
        };
        crafted.seal();
        let Ok(crafted) = Plan::from_json(&serde_json::to_vec(&crafted).unwrap()) else {
            continue;
        };
        accepted += 1;
        let parts: Result<Vec<ShardPart>, _> = (0..crafted.shard_count())
            .map(|k| build_shard(&scene, &crafted, k))
            .collect();
        if let Ok(parts) = parts {
            let _ = merge(&crafted, parts);
        }
    }
    assert!(accepted > 10, "{accepted} crafted plans passed the checks");
}
