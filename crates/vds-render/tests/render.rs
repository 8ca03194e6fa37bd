//! Rendering on whatever adapter the machine has (llvmpipe through GL in CI): the cut at
//! threshold 0 draws exactly what a brute-force draw of the original mesh draws, and golden
//! images of the bunny and a generated CAD scene at a few thresholds hold.

use std::path::{Path, PathBuf};

use vds_build::{build_tree, snap_to_grid, tree_content};
use vds_format::{VdtFile, WriteOptions, encode};
use vds_import::Scene;
use vds_render::{
    CutPipeline, CutUpdate, Gpu, GpuCut, Image, Offscreen, RankMirror, Style, VertexPool,
};
use vds_runtime::{Camera, CornerTracking, Criteria, FrustumMode, Goal, Runtime, Viewpoint};

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

fn golden(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../testdata/golden")
        .join(name)
}

/// The scene (snapped to the file's grid) and its `.vdt` bytes. The file stores each triangle
/// starting at its corner of smallest leaf rank (winding kept); rasterisers interpolate in
/// corner order, so the returned scene's triangles start there too, for pixel-exact
/// comparisons.
fn build(mut scene: Scene) -> (Scene, Vec<u8>) {
    let grid = snap_to_grid(&mut scene);
    let tree = build_tree(&scene);
    for t in &mut scene.triangles {
        let first = (0..3)
            .min_by_key(|&k| tree.vertex_rank[t[k] as usize])
            .unwrap();
        t.rotate_left(first);
    }
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        ..Default::default()
    };
    let bytes = encode(
        &tree_content(&tree, &scene, metadata, grid),
        &WriteOptions::default(),
    )
    .unwrap()
    .0;
    (scene, bytes)
}

fn runtime(bytes: &[u8]) -> Runtime {
    Runtime::new(
        Box::new(VdtFile::from_bytes(bytes.to_vec()).unwrap()),
        CornerTracking::Incidence,
    )
    .unwrap()
}

fn framing(runtime: &Runtime, from: [f32; 3], width: u32, height: u32) -> Camera {
    let root = runtime.cut().node(0);
    Camera::framing(root.sphere_center, root.sphere_radius, from, width, height)
}

struct Renderer {
    gpu: Gpu,
    pipeline: CutPipeline,
}

impl Renderer {
    fn new() -> Renderer {
        let gpu = Gpu::headless().expect("an adapter (llvmpipe on CI)");
        let pipeline = CutPipeline::new(&gpu, vds_render::target_format());
        Renderer { gpu, pipeline }
    }

    /// Adjusts `runtime` for `camera` and renders the cut.
    fn cut(
        &self,
        runtime: &mut Runtime,
        camera: Camera,
        criteria: &Criteria,
        goal: Goal,
        style: &Style,
    ) -> Image {
        let frame = runtime
            .adjust(&Viewpoint::Camera(camera), criteria, goal)
            .unwrap();
        let mut gpu_cut = GpuCut::new(&self.gpu);
        let update = VertexPool::new().collect(runtime.cut_mut(), &frame.changes);
        gpu_cut.apply(&self.gpu, &self.pipeline, &update).unwrap();
        self.draw(&gpu_cut, camera, style)
    }

    fn mesh(&self, scene: &Scene, camera: Camera, style: &Style) -> Image {
        let update =
            CutUpdate::whole_mesh(&scene.positions, &scene.triangles, &scene.triangle_parts);
        let mut gpu_cut = GpuCut::new(&self.gpu);
        gpu_cut.apply(&self.gpu, &self.pipeline, &update).unwrap();
        self.draw(&gpu_cut, camera, style)
    }

    fn draw(&self, gpu_cut: &GpuCut, camera: Camera, style: &Style) -> Image {
        let target = Offscreen::new(&self.gpu, camera.width, camera.height);
        gpu_cut.set_frame(&self.gpu, &camera, style);
        target.render(&self.gpu, gpu_cut, &self.pipeline).unwrap();
        target.read(&self.gpu).unwrap()
    }
}

/// Pixels whose largest channel difference exceeds `tolerance`.
fn differing_pixels(a: &Image, b: &Image, tolerance: u8) -> usize {
    assert_eq!((a.width, a.height), (b.width, b.height));
    a.rgba
        .chunks_exact(4)
        .zip(b.rgba.chunks_exact(4))
        .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > tolerance))
        .count()
}

fn covered_pixels(image: &Image) -> usize {
    let background = &image.rgba[..4];
    image
        .rgba
        .chunks_exact(4)
        .filter(|p| p != &background)
        .count()
}

#[test]
fn threshold_zero_renders_exactly_the_original_mesh() {
    let renderer = Renderer::new();
    for name in ["cow.obj", "as1_assembly.obj"] {
        let (scene, bytes) =
            build(vds_import::load_file(shared(name), &Default::default()).unwrap());
        // The whole model in view, then a close-up that leaves much of it off-screen (where
        // frustum folding and off-screen culling act).
        for zoom in [1.0f32, 0.35] {
            let mut runtime = runtime(&bytes);
            let root = runtime.cut().node(0);
            let camera = Camera::framing(
                root.sphere_center,
                root.sphere_radius * zoom,
                [1.0, 0.4, 1.3],
                320,
                240,
            );
            // Backface folding would (correctly) drop hidden geometry; everything else stays on.
            let criteria = Criteria {
                backface: false,
                frustum: FrustumMode::Fold,
                ..Criteria::default()
            };
            // Culling triangles whose corner nodes are off-screen must not change anything at
            // full detail: such triangles are entirely off-screen.
            let culling = Style {
                cull_outside: true,
                ..Style::default()
            };
            let cut = renderer.cut(
                &mut runtime,
                camera,
                &criteria,
                Goal::Threshold(0.0),
                &culling,
            );
            let brute = renderer.mesh(&scene, camera, &Style::default());
            assert!(
                covered_pixels(&brute) > 5_000,
                "{name}: the model is not in view"
            );
            // Same triangles, same positions, same shader: identical images. Triangles are
            // drawn in a different order, which only matters where two triangles cover a
            // pixel at exactly the same depth (coincident duplicates); none of these meshes
            // has any.
            assert_eq!(differing_pixels(&cut, &brute, 0), 0, "{name}, zoom {zoom}");
            // (The assembly's large plates reach into any close-up, so only the cow is checked.)
            if zoom < 1.0 && name == "cow.obj" {
                assert!(
                    runtime.cut().active_triangle_count() < scene.triangles.len() as u32,
                    "{name}: the close-up should fold off-screen regions"
                );
            }
        }
    }
}

/// Golden images: `VDS_BLESS=1` rewrites them.
///
/// Tolerance: a pixel counts as different when a channel differs by more than 24 of 255, and
/// at most 0.5 % of the pixels may differ. The references come from llvmpipe (Mesa 22.3,
/// LLVM 15) through wgpu's GL backend; other Mesa versions or GPUs rasterise edge pixels and
/// round lighting slightly differently (a few levels of a channel, a fraction of a percent
/// of edge pixels), while a real change — a wrong cut, a missing part, a moved camera —
/// changes thousands of pixels by far more.
fn check_golden(name: &str, image: &Image) {
    let path = golden(name);
    if std::env::var_os("VDS_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image.write_png(&path).unwrap();
    }
    let reference = Image::read_png(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (run with VDS_BLESS=1 to create it)",
            path.display()
        )
    });
    let differing = differing_pixels(image, &reference, 24);
    let allowed = (image.width * image.height) as usize / 200;
    if differing > allowed {
        let failed = std::env::temp_dir().join(format!("vds-failed-{name}"));
        image.write_png(&failed).unwrap();
        panic!(
            "{name}: {differing} pixels differ (at most {allowed}); this run's image is {}",
            failed.display()
        );
    }
}

#[test]
fn golden_images_of_the_bunny_and_a_generated_scene() {
    let renderer = Renderer::new();
    let bunny = vds_import::load_file(shared("bunny.obj"), &Default::default()).unwrap();
    let (_, bunny) = build(bunny);
    let generated = vds_gen::generate(60_000);
    let cad = Scene {
        positions: generated.positions,
        triangles: generated.triangles,
        triangle_parts: generated.triangle_parts,
        part_names: (0..generated.part_count)
            .map(|p| format!("part{p}"))
            .collect(),
        parts: Vec::new(),
        stats: Default::default(),
        warnings: Vec::new(),
    };
    let (_, cad) = build(cad);
    for (name, bytes, from) in [
        ("bunny", &bunny, [0.2f32, 0.3, 1.0]),
        ("cad", &cad, [1.0, 0.7, 1.2]),
    ] {
        for t in [1.0f32, 8.0] {
            let mut runtime = runtime(bytes);
            let camera = framing(&runtime, from, 256, 192);
            let style = Style {
                wireframe: true,
                threshold_px: t,
                cull_outside: true,
                ..Style::default()
            };
            let image = renderer.cut(
                &mut runtime,
                camera,
                &Criteria::default(),
                Goal::Threshold(t),
                &style,
            );
            check_golden(&format!("{name}-t{t}.png"), &image);
        }
    }
}

#[test]
fn png_round_trip() {
    let image = Image {
        width: 3,
        height: 2,
        rgba: (0..24).map(|x| x as u8 * 10).collect(),
    };
    let path = std::env::temp_dir().join(format!("vds-png-{}.png", std::process::id()));
    image.write_png(&path).unwrap();
    assert_eq!(Image::read_png(&path).unwrap(), image);
    std::fs::remove_file(&path).unwrap();
    assert!(Image::read_png(Path::new("/nonexistent/x.png")).is_err());
}

#[test]
fn chunked_slot_buffers_draw_the_same_image() {
    let renderer = Renderer::new();
    let (_, bytes) = build(vds_import::load_file(shared("cow.obj"), &Default::default()).unwrap());
    let criteria = Criteria {
        backface: false,
        ..Criteria::default()
    };
    let style = Style::default();
    let mut images = Vec::new();
    for chunk_slots in [u32::MAX, 700] {
        let mut runtime = runtime(&bytes);
        let camera = framing(&runtime, [1.0, 0.4, 1.3], 320, 240);
        let mut gpu_cut = GpuCut::with_chunk_slots(&renderer.gpu, chunk_slots);
        let mut pool = VertexPool::new();
        // Coarse, then full detail, then coarser again: slots grow across chunk boundaries
        // and later updates write runs that straddle them.
        for t in [16.0, 0.0, 3.0] {
            let frame = runtime
                .adjust(&Viewpoint::Camera(camera), &criteria, Goal::Threshold(t))
                .unwrap();
            let update = pool.collect(runtime.cut_mut(), &frame.changes);
            gpu_cut
                .apply(&renderer.gpu, &renderer.pipeline, &update)
                .unwrap();
        }
        assert!(gpu_cut.slot_count() > 2_000);
        images.push(renderer.draw(&gpu_cut, camera, &style));
    }
    assert!(covered_pixels(&images[0]) > 5_000);
    assert_eq!(differing_pixels(&images[0], &images[1], 0), 0);
}

/// GPU memory follows the cut: along a camera path that refines and coarsens, a vertex pool
/// updated frame by frame holds exactly one vertex per node the active triangles use, reuses
/// the vertices it frees, and draws what a fresh upload of the final cut draws.
#[test]
fn vertex_pool_holds_the_cut_and_draws_like_a_fresh_upload() {
    let renderer = Renderer::new();
    let (_, bytes) = build(vds_import::load_file(shared("cow.obj"), &Default::default()).unwrap());
    let mut runtime = runtime(&bytes);
    let node_count = runtime.cut().store().node_count();
    let camera = framing(&runtime, [1.0, 0.4, 1.3], 320, 240);
    let other = framing(&runtime, [0.3, 0.2, 0.5], 320, 240);
    let mut gpu_cut = GpuCut::new(&renderer.gpu);
    let mut pool = VertexPool::new();
    let mut most = 0;
    for (camera, t) in [
        (camera, 8.0),
        (camera, 0.0),
        (other, 1.0),
        (camera, 4.0),
        (other, 16.0),
    ] {
        let frame = runtime
            .adjust(
                &Viewpoint::Camera(camera),
                &Criteria::default(),
                Goal::Threshold(t),
            )
            .unwrap();
        let update = pool.collect(runtime.cut_mut(), &frame.changes);
        gpu_cut
            .apply(&renderer.gpu, &renderer.pipeline, &update)
            .unwrap();
        let cut = runtime.cut_mut();
        let mut corners: Vec<u32> = cut
            .active_triangles()
            .iter()
            .flat_map(|t| t.corners)
            .collect();
        corners.sort_unstable();
        corners.dedup();
        assert_eq!(pool.vertices_in_use(), corners.len(), "t = {t}");
        most = most.max(corners.len());
    }
    assert!(
        (gpu_cut.vertex_capacity() as usize) < most * 2,
        "vertex buffers grow with the cut: {} for at most {most} vertices",
        gpu_cut.vertex_capacity()
    );
    assert!((most as u32) < node_count);
    let incremental = renderer.draw(&gpu_cut, other, &Style::default());
    let mut fresh = GpuCut::new(&renderer.gpu);
    let update = VertexPool::new().everything(runtime.cut_mut());
    fresh
        .apply(&renderer.gpu, &renderer.pipeline, &update)
        .unwrap();
    let from_scratch = renderer.draw(&fresh, other, &Style::default());
    assert!(covered_pixels(&from_scratch) > 5_000);
    assert_eq!(differing_pixels(&incremental, &from_scratch, 0), 0);
}

/// A rank-tracked cut drawn through a [`RankMirror`] (slots of original ranks, mapped to
/// vertices in the shader) gives exactly the image of the same cut drawn through slot
/// mirroring, frame after frame of a camera path with jumps, both mirrors updated
/// incrementally.
#[test]
fn rank_tracked_cuts_draw_exactly_as_slot_mirrored_cuts() {
    let renderer = Renderer::new();
    let criteria = Criteria::default();
    let style = Style {
        cull_outside: true,
        ..Style::default()
    };
    for name in ["cow.obj", "as1_assembly.obj", "bunny.obj"] {
        let (_, bytes) = build(vds_import::load_file(shared(name), &Default::default()).unwrap());
        let mut slots = runtime(&bytes);
        let mut ranks = Runtime::new(
            Box::new(VdtFile::from_bytes(bytes.clone()).unwrap()),
            CornerTracking::Ranks,
        )
        .unwrap();
        let (mut slot_gpu, mut rank_gpu) = (GpuCut::new(&renderer.gpu), GpuCut::new(&renderer.gpu));
        let (mut pool, mut mirror) = (VertexPool::new(), RankMirror::new());
        let first = mirror.collect(ranks.cut_mut(), &RankMirror::first_changes());
        rank_gpu
            .apply(&renderer.gpu, &renderer.pipeline, &first)
            .unwrap();
        let froms = [
            [1.0, 0.4, 1.3],
            [0.9, 0.5, 1.1],
            [-1.0, 0.2, 0.3],
            [-0.8, -0.3, 0.6],
        ];
        for (step, (from, zoom, t)) in froms
            .into_iter()
            .zip([1.0f32, 0.6, 0.3, 1.4])
            .zip([1.0f32, 3.0, 0.5, 6.0])
            .map(|((f, z), t)| (f, z, t))
            .enumerate()
        {
            let root = slots.cut().node(0);
            let camera = Camera::framing(
                root.sphere_center,
                root.sphere_radius * zoom,
                from,
                320,
                240,
            );
            let view = Viewpoint::Camera(camera);
            let frame = slots.adjust(&view, &criteria, Goal::Threshold(t)).unwrap();
            let update = pool.collect(slots.cut_mut(), &frame.changes);
            slot_gpu
                .apply(&renderer.gpu, &renderer.pipeline, &update)
                .unwrap();
            let frame = ranks.adjust(&view, &criteria, Goal::Threshold(t)).unwrap();
            let update = mirror.collect(ranks.cut_mut(), &frame.changes);
            rank_gpu
                .apply(&renderer.gpu, &renderer.pipeline, &update)
                .unwrap();
            let by_slots = renderer.draw(&slot_gpu, camera, &style);
            let by_ranks = renderer.draw(&rank_gpu, camera, &style);
            assert!(
                covered_pixels(&by_slots) > 2_000,
                "{name} step {step}: the model is not in view"
            );
            assert_eq!(
                differing_pixels(&by_slots, &by_ranks, 0),
                0,
                "{name} step {step}"
            );
        }
    }
}
