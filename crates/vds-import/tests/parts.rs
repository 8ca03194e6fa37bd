//! What each importer keeps of a part besides its triangles: its name, its colour and its
//! parent in the assembly.

use std::path::PathBuf;

use vds_import::{ImportOptions, PartInfo, Scene, load_file};

struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("vds-parts-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn write(&self, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
        let path = self.0.join(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        std::fs::write(&path, bytes).unwrap();
        path
    }
    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn load(path: &PathBuf) -> Scene {
    load_file(path, &ImportOptions::default()).unwrap()
}

fn close(a: Option<[f32; 4]>, b: [f32; 4]) -> bool {
    a.is_some_and(|a| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5))
}

const TWO_GROUPS: &str = "mtllib parts.mtl\n\
    v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n\
    o red\nusemtl red\nf 1 2 3\n\
    o mixed\nusemtl red\nf 1 2 4\nusemtl blue\nf 2 3 4\nf 3 4 5\n";

const MATERIALS: &str = "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\nd 0.5\n";

#[test]
fn obj_groups_take_kd_from_their_materials_averaged_over_triangles() {
    let dir = TempDir::new("obj-kd");
    dir.write("parts.mtl", MATERIALS);
    let scene = load(&dir.write("model.obj", TWO_GROUPS));
    // A group that switches material is still one part.
    assert_eq!(scene.part_names, ["red", "mixed"]);
    assert!(close(scene.parts[0].color, [1.0, 0.0, 0.0, 1.0]));
    // One red triangle, two blue (alpha 0.5): a third red, two thirds blue.
    let third = 1.0 / 3.0;
    assert!(
        close(
            scene.parts[1].color,
            [third, 0.0, 2.0 * third, 2.0 / 3.0 * 0.5 + third]
        ),
        "{:?}",
        scene.parts[1]
    );
    assert!(scene.parts.iter().all(|p| p.parent.is_none()));
}

#[test]
fn obj_without_its_material_library_reads_without_colours() {
    let dir = TempDir::new("obj-missing");
    let scene = load(&dir.write("model.obj", TWO_GROUPS));
    assert_eq!(scene.part_names, ["red", "mixed"]);
    assert_eq!(scene.triangles.len(), 4);
    assert!(scene.parts.iter().all(|p| p.color.is_none()));
}

#[test]
fn obj_material_library_outside_the_folder_is_not_read() {
    let dir = TempDir::new("obj-escape");
    dir.write("parts.mtl", MATERIALS);
    let text = TWO_GROUPS.replace("mtllib parts.mtl", "mtllib ../parts.mtl");
    let scene = load(&dir.write("inner/model.obj", text));
    assert_eq!(scene.triangles.len(), 4);
    assert!(scene.parts.iter().all(|p| p.color.is_none()));
    // Allowed explicitly, it is read.
    let options = ImportOptions {
        allow_external_uris: true,
        ..Default::default()
    };
    let scene = load_file(dir.0.join("inner/model.obj"), &options).unwrap();
    assert!(close(scene.parts[0].color, [1.0, 0.0, 0.0, 1.0]));
}

#[test]
fn obj_from_memory_reads_no_material_library() {
    let mut soup = vds_import::MeshSoup::default();
    vds_import::read_bytes(
        TWO_GROUPS.as_bytes(),
        vds_import::Format::Obj,
        "m",
        &mut soup,
    )
    .unwrap();
    assert!(soup.parts.iter().all(|p| p.color.is_none()));
    assert_eq!(soup.parts.len(), soup.part_names.len());
}

/// A glTF whose nodes are `nodes` (node 0 the scene's root), with one triangle mesh (mesh 0,
/// material 0 of `materials`) and a buffer file beside it.
fn gltf(dir: &TempDir, nodes: &str, materials: &str) -> PathBuf {
    let mut bin = Vec::new();
    for c in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(c.to_le_bytes());
    }
    dir.write("model.bin", bin);
    dir.write(
        "model.gltf",
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":{nodes},"materials":{materials},
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"material":0}}]}},
                      {{"name":"bare","primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "buffers":[{{"byteLength":36,"uri":"model.bin"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}]}}"#
        ),
    )
}

#[test]
fn gltf_parts_keep_the_node_tree_and_base_colour() {
    let dir = TempDir::new("gltf-tree");
    let nodes = r#"[{"name":"Engine","children":[1,4]},
        {"name":"Block","children":[2,3]},
        {"name":"Bolt_12","mesh":0},
        {"name":"Empty"},
        {"mesh":1}]"#;
    let scene = load(&gltf(
        &dir,
        nodes,
        r#"[{"pbrMetallicRoughness":{"baseColorFactor":[0.25,0.5,0.75,1.0]}}]"#,
    ));
    // Grouping nodes above geometry are parts; "Empty" has none below it and is not.
    assert_eq!(scene.part_names, ["Engine", "Block", "Bolt_12", "bare"]);
    let parents: Vec<Option<u32>> = scene.parts.iter().map(|p| p.parent).collect();
    assert_eq!(parents, [None, Some(0), Some(1), Some(0)]);
    assert!(close(scene.parts[2].color, [0.25, 0.5, 0.75, 1.0]));
    // No material: no colour; grouping nodes have none of their own.
    assert_eq!(scene.parts[3].color, None);
    assert_eq!(scene.parts[0].color, None);
    assert_eq!(scene.triangle_parts, [2, 3]);
}

#[test]
fn gltf_material_without_base_colour_factor_is_white() {
    let dir = TempDir::new("gltf-default");
    let scene = load(&gltf(&dir, r#"[{"name":"p","mesh":0}]"#, "[{}]"));
    assert_eq!(
        scene.parts,
        [PartInfo {
            parent: None,
            color: Some([1.0; 4])
        }]
    );
}

fn ply(header_props: &str, faces_props: &str, vertices: &str, faces: &str) -> String {
    format!(
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
         property float z\n{header_props}element face 2\nproperty list uchar int vertex_indices\n\
         {faces_props}end_header\n{vertices}{faces}"
    )
}

#[test]
fn ply_face_colours_are_averaged_per_part() {
    let dir = TempDir::new("ply-face");
    let text = ply(
        "",
        "property int part\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n",
        "0 0 0\n1 0 0\n0 1 0\n0 0 1\n",
        "3 0 1 2 7 255 0 0\n3 0 1 3 9 0 0 255\n",
    );
    let scene = load(&dir.write("model.ply", text));
    assert_eq!(scene.part_names, ["model part 7", "model part 9"]);
    assert!(close(scene.parts[0].color, [1.0, 0.0, 0.0, 1.0]));
    assert!(close(scene.parts[1].color, [0.0, 0.0, 1.0, 1.0]));
}

#[test]
fn ply_vertex_colours_are_averaged_over_the_corners() {
    let dir = TempDir::new("ply-vertex");
    let text = ply(
        "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n",
        "",
        "0 0 0 255 0 0 255\n1 0 0 255 0 0 255\n0 1 0 0 255 0 255\n0 0 1 0 255 0 255\n",
        "3 0 1 2\n3 1 2 3\n",
    );
    let scene = load(&dir.write("model.ply", text));
    // Corner means: (2/3, 1/3, 0) and (1/3, 2/3, 0); their mean is (1/2, 1/2, 0).
    assert!(
        close(scene.parts[0].color, [0.5, 0.5, 0.0, 1.0]),
        "{:?}",
        scene.parts
    );
}

#[test]
fn ply_binary_vertex_colours_take_the_fast_path_too() {
    let dir = TempDir::new("ply-binary");
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
        property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n\
        property uchar blue\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n"
        .to_vec();
    for (p, rgb) in [([0f32, 0.0, 0.0], [0u8, 0, 255]); 1].into_iter().chain([
        ([1.0, 0.0, 0.0], [0, 0, 255]),
        ([0.0, 1.0, 0.0], [0, 0, 255]),
    ]) {
        for c in p {
            bytes.extend(c.to_le_bytes());
        }
        bytes.extend(rgb);
    }
    bytes.push(3);
    for i in 0u32..3 {
        bytes.extend(i.to_le_bytes());
    }
    let scene = load(&dir.write("model.ply", bytes));
    assert!(close(scene.parts[0].color, [0.0, 0.0, 1.0, 1.0]));
}

#[test]
fn ply_without_colours_has_none() {
    let dir = TempDir::new("ply-none");
    let text = ply("", "", "0 0 0\n1 0 0\n0 1 0\n0 0 1\n", "3 0 1 2\n3 1 2 3\n");
    let scene = load(&dir.write("model.ply", text));
    assert_eq!(scene.parts, [PartInfo::default()]);
}

/// A binary STL of two triangles with the given attribute words and header.
fn stl(header: &[u8], attributes: [u16; 2]) -> Vec<u8> {
    let mut bytes = header.to_vec();
    bytes.resize(80, 0);
    bytes.extend(2u32.to_le_bytes());
    for (k, attribute) in attributes.into_iter().enumerate() {
        bytes.extend([0u8; 12]);
        for p in [[0f32, 0.0, k as f32], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
            for c in p {
                bytes.extend(c.to_le_bytes());
            }
        }
        bytes.extend(attribute.to_le_bytes());
    }
    bytes
}

#[test]
fn stl_viscam_colour_words_with_bit_15_set_give_the_colour() {
    let dir = TempDir::new("stl-viscam");
    // Red 31 (bits 10-14), valid; the second facet has no colour (bit 15 clear).
    let scene = load(&dir.write("part.stl", stl(b"binary", [0x8000 | (31 << 10), 0x1234])));
    assert_eq!(scene.part_names, ["part"]);
    assert!(close(scene.parts[0].color, [1.0, 0.0, 0.0, 1.0]));
}

#[test]
fn stl_with_no_valid_colour_word_has_none() {
    let dir = TempDir::new("stl-none");
    let scene = load(&dir.write("part.stl", stl(b"binary", [0, 0x7fff])));
    assert_eq!(scene.parts[0].color, None);
}

#[test]
fn stl_magics_header_colour_stands_in_for_facets_without_their_own() {
    let dir = TempDir::new("stl-magics");
    let header = b"COLOR=\x00\xff\x00\xff MATERIAL=";
    // Facet 1: own colour (bit 15 clear), blue in bits 10-14; facet 2: the object's green.
    let scene = load(&dir.write("part.stl", stl(header, [31 << 10, 0x8000])));
    assert!(
        close(scene.parts[0].color, [0.0, 0.5, 0.5, 1.0]),
        "{:?}",
        scene.parts
    );
}

#[test]
fn appended_files_keep_their_parents_relative_to_their_own_parts() {
    let dir = TempDir::new("append");
    let first = dir.write("a.stl", stl(b"binary", [0, 0]));
    let nodes = r#"[{"name":"top","children":[1]},{"name":"leaf","mesh":0}]"#;
    let second = gltf(&dir, nodes, "[{}]");
    let scene = vds_import::load_files(&[first, second], &ImportOptions::default()).unwrap();
    assert_eq!(scene.part_names, ["a", "top", "leaf"]);
    let parents: Vec<Option<u32>> = scene.parts.iter().map(|p| p.parent).collect();
    assert_eq!(parents, [None, None, Some(1)]);
}

/// A PNG of `texels` repeated over `width` × `height`.
fn png(width: u32, height: u32, texels: &[[u8; 4]]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().unwrap();
    let data: Vec<u8> = (0..(width * height) as usize)
        .flat_map(|i| texels[i % texels.len()])
        .collect();
    writer.write_image_data(&data).unwrap();
    writer.finish().unwrap();
    out
}

#[test]
fn gltf_three_materials_textures_and_a_nested_transform() {
    use base64::Engine as _;
    let dir = TempDir::new("gltf-three");
    let mut bin = Vec::new();
    for c in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(c.to_le_bytes());
    }
    dir.write("model.bin", bin);
    // External texture: half black, half white, averaging to 0.5 in linear light.
    dir.write(
        "tex.png",
        png(4, 4, &[[0, 0, 0, 255], [255, 255, 255, 255]]),
    );
    // Embedded texture: sRGB 188 grey, linear ≈ 0.5029.
    let embedded =
        base64::engine::general_purpose::STANDARD.encode(png(2, 2, &[[188, 188, 188, 255]]));
    let mesh =
        |m: u32| format!(r#"{{"primitives":[{{"attributes":{{"POSITION":0}},"material":{m}}}]}}"#);
    let path = dir.write(
        "model.gltf",
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":[{{"name":"Root","children":[1,2]}},
                     {{"name":"Plain","mesh":0}},
                     {{"name":"Sub","translation":[5,0,0],"children":[3,4]}},
                     {{"name":"Textured","mesh":1}},
                     {{"name":"Lost","mesh":2}}],
            "materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[0.2,0.4,0.6,1.0]}}}},
                         {{"pbrMetallicRoughness":{{"baseColorFactor":[1.0,0.5,1.0,1.0],"baseColorTexture":{{"index":0}}}}}},
                         {{"pbrMetallicRoughness":{{"baseColorFactor":[0.3,0.3,0.3,1.0],"baseColorTexture":{{"index":1}}}}}},
                         {{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":2}}}}}}],
            "textures":[{{"source":0}},{{"source":1}},{{"source":2}}],
            "images":[{{"uri":"tex.png"}},{{"uri":"missing.png"}},{{"uri":"data:image/png;base64,{embedded}"}}],
            "meshes":[{},{},{}],
            "buffers":[{{"byteLength":36,"uri":"model.bin"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}]}}"#,
            mesh(0),
            mesh(1),
            mesh(2)
        ),
    );
    let scene = load(&path);
    assert_eq!(
        scene.part_names,
        ["Root", "Plain", "Sub", "Textured", "Lost"]
    );
    let parents: Vec<Option<u32>> = scene.parts.iter().map(|p| p.parent).collect();
    assert_eq!(parents, [None, Some(0), Some(0), Some(2), Some(2)]);
    assert!(
        close(scene.parts[1].color, [0.2, 0.4, 0.6, 1.0]),
        "{:?}",
        scene.parts[1]
    );
    // The texture's mean times the factor.
    assert!(
        close(scene.parts[3].color, [0.5, 0.25, 0.5, 1.0]),
        "{:?}",
        scene.parts[3]
    );
    // The missing texture: the factor alone, and a warning naming the image.
    assert!(
        close(scene.parts[4].color, [0.3, 0.3, 0.3, 1.0]),
        "{:?}",
        scene.parts[4]
    );
    assert_eq!(scene.warnings.len(), 1, "{:?}", scene.warnings);
    assert!(
        scene.warnings[0].contains("missing.png") && scene.warnings[0].contains("model.gltf"),
        "{:?}",
        scene.warnings
    );
    // The nested node's transform moved its triangles.
    let shifted = scene
        .triangles
        .iter()
        .zip(&scene.triangle_parts)
        .filter(|(_, p)| **p >= 3)
        .flat_map(|(t, _)| t.iter().map(|&v| scene.positions[v as usize][0]))
        .fold(f32::MAX, f32::min);
    assert_eq!(shifted, 5.0);

    // The embedded texture, on its own.
    let embedded_only = dir.write(
        "embedded.gltf",
        std::fs::read_to_string(&path)
            .unwrap()
            .replace(r#""material":0}]}"#, r#""material":3}]}"#),
    );
    let scene = load(&embedded_only);
    let grey = 0.5029;
    assert!(
        scene.parts[1]
            .color
            .is_some_and(|c| c[..3].iter().all(|v| (v - grey).abs() < 1e-3)),
        "{:?}",
        scene.parts[1]
    );
}

#[test]
fn obj_missing_material_library_is_a_warning_naming_it() {
    let dir = TempDir::new("obj-warning");
    let scene = load(&dir.write("model.obj", TWO_GROUPS));
    assert_eq!(scene.warnings.len(), 1, "{:?}", scene.warnings);
    assert!(
        scene.warnings[0].contains("parts.mtl") && scene.warnings[0].contains("model.obj"),
        "{:?}",
        scene.warnings
    );
    dir.write("parts.mtl", MATERIALS);
    assert!(load(&dir.join("model.obj")).warnings.is_empty());
}
