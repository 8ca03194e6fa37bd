//! What a design review relies on, rendered on the machine's adapter (llvmpipe in CI) over
//! the AS1 assembly (18 parts) and a generated CAD scene (many parts merged at coarse levels):
//! the file's colours land where the parts are, a hidden part leaves no pixel at any
//! threshold, a section plane removes everything on its side, and a pick returns the part
//! that a brute-force draw of the original mesh shows at that pixel.

use std::path::PathBuf;

use vds_format::VdtFile;
use vds_import::Scene;
use vds_render::{
    Colouring, CutPipeline, CutUpdate, Gpu, GpuCut, Hit, Image, Offscreen, PartLook, SectionPlane,
    Style, VertexPool, pick, pick_region,
};
use vds_runtime::{Camera, CornerTracking, Criteria, Goal, Runtime, Viewpoint};

/// The three colours the tests paint parts with: each has one dominant channel.
const PRIMARIES: [[f32; 3]; 3] = [[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]];

struct Fixture {
    scene: Scene,
    bytes: Vec<u8>,
    gpu: Gpu,
    pipeline: CutPipeline,
}

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

impl Fixture {
    fn new(mut scene: Scene) -> Fixture {
        let bytes = vds_build::encode_scene(&mut scene, "test", &Default::default()).unwrap();
        let gpu = Gpu::headless().expect("an adapter (llvmpipe on CI)");
        let pipeline = CutPipeline::new(&gpu, vds_render::target_format());
        Fixture {
            scene,
            bytes,
            gpu,
            pipeline,
        }
    }

    fn as1() -> Fixture {
        Fixture::new(
            vds_import::load_file(shared("as1_assembly.obj"), &Default::default()).unwrap(),
        )
    }

    fn generated() -> Fixture {
        let generated = vds_gen::generate(40_000);
        Fixture::new(Scene {
            positions: generated.positions,
            triangles: generated.triangles,
            triangle_parts: generated.triangle_parts,
            part_names: (0..generated.part_count)
                .map(|p| format!("part {p}"))
                .collect(),
            parts: Vec::new(),
            stats: Default::default(),
            warnings: Vec::new(),
        })
    }

    fn parts(&self) -> usize {
        self.scene.part_names.len()
    }

    fn runtime(&self) -> Runtime {
        Runtime::new(
            Box::new(VdtFile::from_bytes(self.bytes.clone()).unwrap()),
            CornerTracking::Incidence,
        )
        .unwrap()
    }

    /// Cameras around and into the model.
    fn cameras(&self) -> Vec<Camera> {
        self.cameras_of_size(160, 120)
    }

    /// [`Fixture::cameras`] with images of `width` × `height`.
    fn cameras_of_size(&self, width: u32, height: u32) -> Vec<Camera> {
        let runtime = self.runtime();
        let root = runtime.cut().node(0);
        [
            ([1.0, 0.6, 0.8], 1.0),
            ([-0.7, -0.4, 0.6], 1.0),
            ([0.3, 1.0, -0.5], 0.5),
        ]
        .into_iter()
        .map(|(from, zoom)| {
            Camera::framing(
                root.sphere_center,
                root.sphere_radius * zoom,
                from,
                width,
                height,
            )
        })
        .collect()
    }

    /// The cut at `threshold` for `camera`, on the GPU with `looks`.
    fn cut(&self, camera: Camera, threshold: f32, looks: &[PartLook]) -> GpuCut {
        self.cut_with(camera, threshold, looks, &Criteria::default())
    }

    /// [`Fixture::cut`] under `criteria`.
    fn cut_with(
        &self,
        camera: Camera,
        threshold: f32,
        looks: &[PartLook],
        criteria: &Criteria,
    ) -> GpuCut {
        let mut runtime = self.runtime();
        let frame = runtime
            .adjust(
                &Viewpoint::Camera(camera),
                criteria,
                Goal::Threshold(threshold),
            )
            .unwrap();
        let update = VertexPool::new().collect(runtime.cut_mut(), &frame.changes);
        let mut gpu_cut = GpuCut::new(&self.gpu);
        gpu_cut.set_parts(&self.gpu, &self.pipeline, looks);
        gpu_cut.apply(&self.gpu, &self.pipeline, &update).unwrap();
        gpu_cut
    }

    /// The original mesh on the GPU with `looks`.
    fn brute_force(&self, looks: &[PartLook]) -> GpuCut {
        let s = &self.scene;
        let update = CutUpdate::whole_mesh(&s.positions, &s.triangles, &s.triangle_parts);
        let mut gpu_cut = GpuCut::new(&self.gpu);
        gpu_cut.set_parts(&self.gpu, &self.pipeline, looks);
        gpu_cut.apply(&self.gpu, &self.pipeline, &update).unwrap();
        gpu_cut
    }

    fn draw(&self, gpu_cut: &GpuCut, camera: Camera, style: &Style) -> Image {
        let target = Offscreen::new(&self.gpu, camera.width, camera.height);
        gpu_cut.set_frame(&self.gpu, &camera, style);
        target.render(&self.gpu, gpu_cut, &self.pipeline).unwrap();
        target.read(&self.gpu).unwrap()
    }

    /// The part and position at every pixel, row by row.
    fn ids(&self, gpu_cut: &GpuCut, camera: Camera, style: &Style) -> Vec<Option<Hit>> {
        let window = [0, 0, camera.width, camera.height];
        pick_region(&self.gpu, gpu_cut, &self.pipeline, &camera, style, window).unwrap()
    }
}

/// Every part coloured by its id: primaries in turn.
fn primary_looks(parts: usize) -> Vec<PartLook> {
    (0..parts)
        .map(|p| PartLook {
            colour: Some(PRIMARIES[p % 3]),
            ..Default::default()
        })
        .collect()
}

/// The dominant channel of an sRGB pixel, if one channel clearly leads (shading scales all
/// three alike; edges and the background lead with none).
fn dominant(pixel: &[u8]) -> Option<usize> {
    let (k, &top) = pixel[..3].iter().enumerate().max_by_key(|(_, v)| **v)?;
    let second = pixel[..3]
        .iter()
        .enumerate()
        .filter(|(j, _)| *j != k)
        .map(|(_, v)| *v)
        .max()?;
    (top >= 40 && top >= second.saturating_mul(2)).then_some(k)
}

/// The viewer's style: file colours, and no coarse stand-ins of off-screen regions.
fn style() -> Style {
    Style {
        colouring: Colouring::File,
        cull_outside: true,
        ..Style::default()
    }
}

#[test]
fn the_files_colours_show_where_the_parts_are() {
    for fixture in [Fixture::as1(), Fixture::generated()] {
        let looks = primary_looks(fixture.parts());
        for camera in fixture.cameras() {
            for threshold in [0.0, 1.0, 8.0] {
                let gpu_cut = fixture.cut(camera, threshold, &looks);
                let image = fixture.draw(&gpu_cut, camera, &style());
                let ids = fixture.ids(&gpu_cut, camera, &style());
                let (mut agree, mut covered) = (0, 0);
                for (pixel, hit) in image.rgba.chunks_exact(4).zip(&ids) {
                    let Some(hit) = hit else { continue };
                    covered += 1;
                    if dominant(pixel) == Some(hit.part as usize % 3) {
                        agree += 1;
                    }
                }
                assert!(
                    covered > 500,
                    "the model covers the view ({covered} pixels)"
                );
                // Faces lit edge-on go dark enough that no channel leads: allow a few.
                assert!(
                    agree * 100 >= covered * 95,
                    "threshold {threshold}: {agree} of {covered} pixels show their part's colour"
                );
            }
        }
    }
}

#[test]
fn the_part_palette_ignores_the_files_colours() {
    let fixture = Fixture::as1();
    // Every part coloured pure red in the file: the palette colouring must not show it.
    let looks = vec![
        PartLook {
            colour: Some(PRIMARIES[0]),
            ..Default::default()
        };
        fixture.parts()
    ];
    let camera = fixture.cameras()[0];
    let gpu_cut = fixture.cut(camera, 1.0, &looks);
    let red = |style: &Style| {
        let image = fixture.draw(&gpu_cut, camera, style);
        image
            .rgba
            .chunks_exact(4)
            .filter(|p| dominant(p) == Some(0))
            .count()
    };
    let palette = Style {
        colouring: Colouring::Parts,
        ..style()
    };
    assert!(red(&style()) > 500);
    assert!(red(&palette) < red(&style()) / 4);
}

#[test]
fn a_hidden_part_leaves_no_pixel_at_any_threshold() {
    for fixture in [Fixture::as1(), Fixture::generated()] {
        // The part drawn in red: the one that covers most of the first view at full detail.
        let camera = fixture.cameras()[0];
        let ids = fixture.ids(&fixture.brute_force(&[]), camera, &style());
        let mut counts = vec![0usize; fixture.parts()];
        for hit in ids.iter().flatten() {
            counts[hit.part as usize] += 1;
        }
        let target = (0..counts.len()).max_by_key(|&p| counts[p]).unwrap();
        let mut looks: Vec<PartLook> = (0..fixture.parts())
            .map(|_| PartLook {
                colour: Some(PRIMARIES[2]),
                ..Default::default()
            })
            .collect();
        looks[target].colour = Some(PRIMARIES[0]);
        let red = |image: &Image| {
            image
                .rgba
                .chunks_exact(4)
                .filter(|p| dominant(p) == Some(0))
                .count()
        };
        for camera in fixture.cameras() {
            for threshold in [0.0, 1.0, 8.0, 30.0] {
                let shown = fixture.cut(camera, threshold, &looks);
                let before = red(&fixture.draw(&shown, camera, &style()));
                looks[target].hidden = true;
                let hidden = fixture.cut(camera, threshold, &looks);
                let image = fixture.draw(&hidden, camera, &style());
                let ids = fixture.ids(&hidden, camera, &style());
                looks[target].hidden = false;
                assert_eq!(
                    red(&image),
                    0,
                    "threshold {threshold}: hidden part's pixels"
                );
                assert!(
                    ids.iter().flatten().all(|h| h.part as usize != target),
                    "threshold {threshold}: the hidden part is picked"
                );
                if camera == fixture.cameras()[0] {
                    assert!(
                        before > 100,
                        "threshold {threshold}: the part shows ({before})"
                    );
                }
            }
        }
    }
}

#[test]
fn a_section_plane_removes_everything_on_its_side() {
    for fixture in [Fixture::as1(), Fixture::generated()] {
        let looks = primary_looks(fixture.parts());
        let root = fixture.runtime().cut().node(0);
        for (normal, threshold) in [
            ([1.0f32, 0.0, 0.0], 0.0),
            ([0.3, -0.8, 0.5], 1.0),
            ([0.0, 0.0, 1.0], 8.0),
        ] {
            let length =
                (normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]).sqrt();
            let normal = normal.map(|v: f32| v / length);
            // Through the centre of the model.
            let offset = -(0..3)
                .map(|k| normal[k] * root.sphere_center[k])
                .sum::<f32>();
            let plane = SectionPlane { normal, offset };
            let sectioned = Style {
                sections: [Some(plane), None, None],
                ..style()
            };
            let side = |hit: &Hit| {
                (0..3).map(|k| plane.normal[k] * hit.world[k]).sum::<f32>() + plane.offset
            };
            for camera in fixture.cameras() {
                let gpu_cut = fixture.cut(camera, threshold, &looks);
                let whole = fixture.ids(&gpu_cut, camera, &style());
                let cut = fixture.ids(&gpu_cut, camera, &sectioned);
                let beyond = whole.iter().flatten().filter(|h| side(h) > 0.0).count();
                assert!(beyond > 50, "the plane has something to remove ({beyond})");
                let tolerance = root.sphere_radius * 1e-5;
                let left: Vec<_> = cut
                    .iter()
                    .flatten()
                    .filter(|h| side(h) > tolerance)
                    .collect();
                assert!(
                    left.is_empty(),
                    "{} pixels beyond the plane remain",
                    left.len()
                );
                assert!(
                    cut.iter().flatten().count() > 50,
                    "the other side still shows"
                );
            }
        }
    }
}

#[test]
fn a_pick_returns_the_part_that_a_brute_force_draw_shows() {
    for fixture in [Fixture::as1(), Fixture::generated()] {
        let brute = fixture.brute_force(&[]);
        let cameras = fixture.cameras_of_size(320, 240);
        let truths: Vec<_> = cameras
            .iter()
            .map(|&camera| fixture.ids(&brute, camera, &style()))
            .collect();
        for (threshold, margin, step) in [(0.0f32, 1usize, 8), (1.0, 2, 8), (8.0, 9, 3)] {
            let (mut checked, mut wrong) = (0, 0);
            for (&camera, truth) in cameras.iter().zip(&truths) {
                let width = camera.width as usize;
                // Backface folding drops hidden geometry whose coarse stand-ins may show at
                // the rim of a solid: off here, so that the cut at 0 px is the original mesh.
                let criteria = Criteria {
                    backface: false,
                    ..Criteria::default()
                };
                let gpu_cut = fixture.cut_with(camera, threshold, &[], &criteria);
                // Pixels whose neighbourhood shows one part in the original: a cut within
                // `threshold` pixels of it shows that part there too. (At threshold 0 the cut's
                // triangles are the original ones with corners in another order: depth ties
                // between coincident faces and edge pixels may go either way, so a pixel's
                // neighbours must agree too.)
                for y in (margin..camera.height as usize - margin).step_by(step) {
                    for x in (margin..width - margin).step_by(step) {
                        let Some(expected) = truth[y * width + x] else {
                            continue;
                        };
                        let uniform = (y - margin..=y + margin).all(|v| {
                            (x - margin..=x + margin).all(|u| {
                                truth[v * width + u].map(|h| h.part) == Some(expected.part)
                            })
                        });
                        if !uniform {
                            continue;
                        }
                        let got = pick(
                            &fixture.gpu,
                            &gpu_cut,
                            &fixture.pipeline,
                            &camera,
                            &style(),
                            x as u32,
                            y as u32,
                        )
                        .unwrap();
                        checked += 1;
                        if got.map(|h| h.part) != Some(expected.part) {
                            wrong += 1;
                        }
                    }
                }
            }
            assert!(
                checked > 10,
                "threshold {threshold}: {checked} pixels checked"
            );
            // At full detail the cut is the original mesh: every pick agrees. Coarser cuts
            // may still differ where a part is thinner than the threshold.
            let allowed = if threshold == 0.0 { 0 } else { checked / 20 };
            assert!(
                wrong <= allowed,
                "threshold {threshold}: {wrong} of {checked} picks differ from the brute-force draw"
            );
        }
    }
}

#[test]
fn one_pixel_picks_agree_with_the_whole_id_image() {
    let fixture = Fixture::as1();
    let camera = fixture.cameras()[0];
    let gpu_cut = fixture.cut(camera, 1.0, &[]);
    let ids = fixture.ids(&gpu_cut, camera, &style());
    let mut hits = 0;
    for (x, y) in [(80, 60), (10, 10), (100, 70), (60, 50), (159, 119), (0, 0)] {
        let one = pick(
            &fixture.gpu,
            &gpu_cut,
            &fixture.pipeline,
            &camera,
            &style(),
            x,
            y,
        )
        .unwrap();
        let whole = ids[(y * camera.width + x) as usize];
        assert_eq!(one.map(|h| h.part), whole.map(|h| h.part), "pixel {x},{y}");
        if let (Some(a), Some(b)) = (one, whole) {
            hits += 1;
            let d: f32 = (0..3).map(|k| (a.world[k] - b.world[k]).abs()).sum();
            assert!(d < 1e-2, "pixel {x},{y}: {:?} vs {:?}", a.world, b.world);
        }
    }
    assert!(hits >= 2);
    assert_eq!(
        pick(
            &fixture.gpu,
            &gpu_cut,
            &fixture.pipeline,
            &camera,
            &style(),
            160,
            5
        )
        .unwrap(),
        None,
        "outside the view"
    );
}
