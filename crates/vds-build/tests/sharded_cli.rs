//! `vds-build plan | shard | merge` as a user or a batch scheduler runs them: the recipes of
//! `docs/scaling.md` (run from the document itself, shards as parallel processes) write the
//! in-memory build's file byte for byte, and a merge with a wrong set of parts fails naming
//! the file and writes nothing.

use std::path::{Path, PathBuf};
use std::process::Command;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-sharded-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn model(name: &str) -> PathBuf {
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    match name {
        "as1_assembly.obj" => {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/as1_assembly.obj")
        }
        _ => shared.join(name),
    }
}

fn build(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_vds-build"))
        .args(args)
        .output()
        .unwrap()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn succeeded(run: &std::process::Output) {
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// The shell script that follows `<!-- test: NAME -->` in `docs/scaling.md`.
fn recipe(name: &str) -> String {
    let doc = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/scaling.md"),
    )
    .unwrap();
    let marker = format!("<!-- test: {name} -->");
    let after = &doc[doc.find(&marker).expect("the recipe's marker") + marker.len()..];
    let body = after
        .trim_start()
        .strip_prefix("```sh\n")
        .expect("a sh block after the marker");
    body[..body.find("```").expect("the block's end")].to_string()
}

fn run_recipe(name: &str, input: &Path, shards: u32) {
    // One folder per recipe and input: tests run side by side.
    let file = input.file_name().unwrap().to_string_lossy();
    let dir = temp_dir(&format!("{name}-{file}"));
    let expected = dir.join("in-memory.vdt");
    succeeded(&build(&[path(input), "-o", path(&expected), "-q"]));
    let output = dir.join("sharded.vdt");
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_vds-build"));
    let search = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let run = Command::new("bash")
        .args(["-euo", "pipefail", "-c", &recipe(name)])
        .env("PATH", search)
        .env("INPUT", input)
        .env("N", shards.to_string())
        .env("WORK", &dir)
        .env("OUTPUT", &output)
        .output()
        .unwrap();
    succeeded(&run);
    let (a, b) = (
        std::fs::read(&expected).unwrap(),
        std::fs::read(&output).unwrap(),
    );
    assert!(
        a == b,
        "{name} recipe, {}: the merged file differs",
        input.display()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_background_process_recipe_writes_the_in_memory_file() {
    run_recipe("background", &model("as1_assembly.obj"), 3);
    run_recipe("background", &model("bunny.obj"), 4);
}

#[test]
fn the_xargs_recipe_writes_the_in_memory_file() {
    run_recipe("xargs", &model("cow.obj"), 5);
    // Other formats: a binary PLY, and an STL written here from the bundled assembly.
    run_recipe("xargs", &model("bone.ply"), 3);
    let dir = temp_dir("stl");
    let stl = dir.join("as1.stl");
    let scene = vds_import::load_file(model("as1_assembly.obj"), &Default::default()).unwrap();
    let mut bytes = vec![0u8; 80];
    bytes.extend_from_slice(&(scene.triangles.len() as u32).to_le_bytes());
    for t in &scene.triangles {
        bytes.extend_from_slice(&[0u8; 12]);
        for &v in t {
            for c in scene.positions[v as usize] {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
        }
        bytes.extend_from_slice(&[0u8; 2]);
    }
    std::fs::write(&stl, bytes).unwrap();
    run_recipe("background", &stl, 4);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn merge_with_a_wrong_set_of_parts_fails_and_writes_nothing() {
    let dir = temp_dir("wrong-set");
    let input = model("as1_assembly.obj");
    let plan = dir.join("plan.json");
    succeeded(&build(&[
        "plan",
        path(&input),
        "--shards",
        "3",
        "-o",
        path(&plan),
        "-q",
    ]));
    let other = dir.join("other.json");
    succeeded(&build(&[
        "plan",
        path(&input),
        "--shards",
        "2",
        "-o",
        path(&other),
        "-q",
    ]));
    let part = |plan: &Path, k: u32, name: &str| {
        let out = dir.join(name);
        succeeded(&build(&[
            "shard",
            path(plan),
            "--index",
            &k.to_string(),
            "-o",
            path(&out),
            "-q",
        ]));
        out
    };
    let parts: Vec<PathBuf> = (0..3)
        .map(|k| part(&plan, k, &format!("s{k}.vdtpart")))
        .collect();
    let foreign = part(&other, 0, "foreign.vdtpart");
    let truncated = dir.join("truncated.vdtpart");
    let bytes = std::fs::read(&parts[2]).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() - 10]).unwrap();
    let out = dir.join("out.vdt");
    let cases: [(&[&Path], &str); 4] = [
        (&[&parts[0], &parts[1]], "missing shard 2 of 3"),
        (
            &[&parts[0], &parts[1], &parts[1], &parts[2]],
            "are both shard 1",
        ),
        (
            &[&foreign, &parts[1], &parts[2]],
            "foreign.vdtpart: built for another plan",
        ),
        (
            &[&parts[0], &parts[1], &truncated],
            "truncated.vdtpart: truncated or damaged",
        ),
    ];
    for (given, message) in cases {
        let mut args = vec!["merge", path(&plan)];
        args.extend(given.iter().map(|p| path(p)));
        args.extend(["-o", path(&out)]);
        let run = build(&args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains(message),
            "expected {message:?} in: {stderr}"
        );
        assert!(!out.exists(), "{message}: an output was written");
    }
    // The right set, then, writes a file that verifies.
    let mut args = vec!["merge", path(&plan)];
    args.extend(parts.iter().map(|p| path(p)));
    args.extend(["-o", path(&out), "--verify", "-q"]);
    succeeded(&build(&args));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_shard_reads_only_its_own_input_file() {
    let dir = temp_dir("inputs");
    let input = dir.join("model.obj");
    std::fs::copy(model("as1_assembly.obj"), &input).unwrap();
    let plan = dir.join("plan.json");
    succeeded(&build(&[
        "plan",
        path(&input),
        "--shards",
        "2",
        "-o",
        path(&plan),
        "-q",
    ]));
    let spill = |k: u32| dir.join(format!("plan.shard-{k}.vdtin"));
    assert!(spill(0).exists() && spill(1).exists());
    // The model is not needed any more.
    std::fs::remove_file(&input).unwrap();
    let out = dir.join("s.vdtpart");
    succeeded(&build(&[
        "shard",
        path(&plan),
        "--index",
        "1",
        "-o",
        path(&out),
        "-q",
    ]));
    std::fs::remove_file(&out).unwrap();

    let run = build(&["shard", path(&plan), "--index", "2", "-o", path(&out)]);
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("the plan has shards 0 to 1"));
    // Shard 0's input in shard 1's place.
    std::fs::copy(spill(0), spill(1)).unwrap();
    let run = build(&["shard", path(&plan), "--index", "1", "-o", path(&out)]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("plan.shard-1.vdtin: the input of shard 0"),
        "{stderr}"
    );
    std::fs::remove_file(spill(1)).unwrap();
    let run = build(&["shard", path(&plan), "--index", "1", "-o", path(&out)]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("plan.shard-1.vdtin"), "{stderr}");
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A glTF assembly (a parent node, two coloured child parts) through the sharded build: the
/// part tree and colours in the metadata are the in-memory build's too.
#[test]
fn a_gltf_assembly_gives_the_in_memory_file() {
    let dir = temp_dir("gltf");
    // A bumpy grid, two meshes of it (the same positions), three parts.
    let n = 40u32;
    let mut bin: Vec<u8> = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let z = ((x * 7 + y * 3) % 5) as f32 * 0.05;
            for c in [x as f32 * 0.1, y as f32 * 0.1, z] {
                bin.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    let positions_bytes = bin.len();
    let mut count = 0;
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let v = y * n + x;
            for i in [v, v + 1, v + n, v + 1, v + n + 1, v + n] {
                bin.extend_from_slice(&i.to_le_bytes());
                count += 1;
            }
        }
    }
    std::fs::write(dir.join("grid.bin"), &bin).unwrap();
    let gltf = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [
    {{"name": "assembly", "mesh": 1, "translation": [0.0, 5.0, 0.0], "children": [1, 2]}},
    {{"name": "left", "mesh": 0}},
    {{"name": "right", "mesh": 1, "translation": [4.5, 0.25, 0.5]}}
  ],
  "meshes": [
    {{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1, "material": 0}}]}},
    {{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1, "material": 1}}]}}
  ],
  "materials": [
    {{"pbrMetallicRoughness": {{"baseColorFactor": [0.8, 0.2, 0.1, 1.0]}}}},
    {{"pbrMetallicRoughness": {{"baseColorFactor": [0.1, 0.3, 0.9, 1.0]}}}}
  ],
  "buffers": [{{"uri": "grid.bin", "byteLength": {total}}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": {positions_bytes}}},
    {{"buffer": 0, "byteOffset": {positions_bytes}, "byteLength": {index_bytes}}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": {vertices}, "type": "VEC3",
      "min": [0, 0, 0], "max": [{extent}, {extent}, 0.2]}},
    {{"bufferView": 1, "componentType": 5125, "count": {count}, "type": "SCALAR"}}
  ]
}}"#,
        total = bin.len(),
        index_bytes = bin.len() - positions_bytes,
        vertices = n * n,
        extent = (n - 1) as f32 * 0.1,
    );
    let input = dir.join("assembly.gltf");
    std::fs::write(&input, gltf).unwrap();
    run_recipe("background", &input, 3);
    // The file states the part tree: the two parts under the assembly, coloured.
    let out = dir.join("x.vdt");
    succeeded(&build(&[path(&input), "-o", path(&out), "-q"]));
    let info = Command::new(env!("CARGO_BIN_EXE_vds-info"))
        .args([path(&out), "--parts", "--json"])
        .output()
        .unwrap();
    succeeded(&info);
    let report: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let parts = report["part_list"].as_array().expect("a part list");
    let named = |name: &str| {
        parts
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("no part {name}: {report}"))
    };
    assert!(
        named("left")["parent"] == named("assembly")["index"],
        "{report}"
    );
    assert!(named("right")["color"].is_array(), "{report}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Page options given to `plan` reach the merged file as they reach an in-memory build's.
#[test]
fn page_options_given_to_plan_shape_the_merged_file() {
    let dir = temp_dir("options");
    let input = model("cow.obj");
    let options = ["--page-bytes", "16KiB", "--zstd-level", "3"];
    let expected = dir.join("in-memory.vdt");
    let mut args = vec![path(&input), "-o", path(&expected), "-q"];
    args.extend(options);
    succeeded(&build(&args));
    let plan = dir.join("plan.json");
    let mut args = vec![
        "plan",
        path(&input),
        "--shards",
        "3",
        "-o",
        path(&plan),
        "-q",
    ];
    args.extend(options);
    succeeded(&build(&args));
    let parts: Vec<PathBuf> = (0..3)
        .map(|k| {
            let out = dir.join(format!("s{k}.vdtpart"));
            let index = k.to_string();
            succeeded(&build(&[
                "shard",
                path(&plan),
                "--index",
                &index,
                "-o",
                path(&out),
                "-q",
            ]));
            out
        })
        .collect();
    let merged = dir.join("merged.vdt");
    let mut args = vec!["merge", path(&plan)];
    args.extend(parts.iter().map(|p| path(p)));
    args.extend(["-o", path(&merged), "-q"]);
    succeeded(&build(&args));
    let (a, b) = (
        std::fs::read(&expected).unwrap(),
        std::fs::read(&merged).unwrap(),
    );
    assert!(a == b, "the merged file differs");
    // The options took: smaller pages than the default make more of them.
    let default = dir.join("default.vdt");
    succeeded(&build(&[path(&input), "-o", path(&default), "-q"]));
    assert_ne!(std::fs::read(&default).unwrap(), a);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `vds-build --memory-limit` on a generated 3 M-triangle scene: the in-memory build's file,
/// byte for byte, with a peak (the process's `VmHWM`, as the build reports it, import and plan
/// included) within a limit that the in-memory build of the same scene goes over, and that
/// the input file alone (72 MB, mapped) and its soup in memory (55 MB) would together exceed.
#[test]
fn a_build_within_a_memory_limit_writes_the_same_file_within_the_limit() {
    let dir = temp_dir("memory-limit");
    let input = dir.join("scene.ply");
    vds_gen::write_ply_streamed(
        3_000_000,
        &mut std::io::BufWriter::new(std::fs::File::create(&input).unwrap()),
    )
    .unwrap();
    let peak = |run: &std::process::Output| -> u64 {
        succeeded(run);
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        report["peak_rss_bytes"].as_u64().expect("a peak on Linux")
    };
    const LIMIT: u64 = 80 << 20;
    let expected = dir.join("in-memory.vdt");
    let in_memory = peak(&build(&[path(&input), "-o", path(&expected), "--json"]));
    assert!(
        in_memory > LIMIT,
        "the in-memory build peaks at {in_memory} B: the scene is too small to test the limit"
    );
    let output = dir.join("limited.vdt");
    let run = build(&[
        path(&input),
        "-o",
        path(&output),
        "--memory-limit",
        "80MiB",
        "--json",
    ]);
    let limited = peak(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert!(report["shards"].as_u64().unwrap() > 1, "{report}");
    assert!(
        limited <= LIMIT,
        "peak {limited} B over the limit of {LIMIT} B: {report}"
    );
    let import = report["import_peak_rss_bytes"].as_u64().unwrap();
    assert!(import <= LIMIT, "import and plan peak {import} B: {report}");
    assert!(
        std::fs::metadata(&input).unwrap().len() > LIMIT / 2,
        "the test needs an input of a size near the limit"
    );
    assert!(std::fs::read(&expected).unwrap() == std::fs::read(&output).unwrap());
    // The temporary folder of shard inputs and parts is gone.
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 3, "{left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A limit that cannot hold even the process itself is refused before anything is read, and
/// `--memory-limit` refuses what a sharded build cannot do.
#[test]
fn a_memory_limit_refuses_what_it_cannot_keep() {
    let dir = temp_dir("memory-limit-refusals");
    let output = dir.join("x.vdt");
    let input = model("bunny.obj");
    for (extra, says) in [
        (&["--memory-limit", "1MiB"][..], "too small"),
        (&["--memory-limit", "1GiB", "--weld", "0.001"][..], "--weld"),
        (
            &["--memory-limit", "1GiB", "--builder", "qem"][..],
            "octree",
        ),
    ] {
        let mut args = vec![path(&input), "-o", path(&output)];
        args.extend_from_slice(extra);
        let run = build(&args);
        assert!(!run.status.success());
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(stderr.contains(says), "{extra:?}: {stderr}");
        assert!(!output.exists());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
