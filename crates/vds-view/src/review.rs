//! The design-review window of the panel: the assembly tree with a checkbox per part and a
//! search by name, what the last click picked (name, path, triangles, world position) with
//! hide / isolate / show all, the section planes, and measurements between two clicks
//! snapped to the original vertices.
//!
//! [`Review`] owns that state; the window turns clicks into [`Review::picked`] and
//! [`Review::measured`] and re-uploads the part looks when [`Review::take_looks_changed`]
//! says so.

use vds_render::{Hit, MAX_SECTIONS, SectionPlane};

use vds_runtime::nearest::NearestLeaf;

use crate::parts::Parts;
use crate::probe::Measurement;

/// The most search results or tree rows listed at once (a ship has hundreds of thousands of
/// parts; egui lays out every row it is given).
const MAX_ROWS: usize = 500;

/// One section plane as the panel edits it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SectionEdit {
    /// Clipping with it.
    pub enabled: bool,
    /// 0, 1, 2: the x, y or z axis; 3: the normal as given on the command line.
    pub axis: usize,
    /// A given normal (for axis 3).
    pub normal: [f32; 3],
    /// Where the plane crosses its axis (world units along the normal).
    pub position: f32,
    /// Cut away the other side.
    pub flipped: bool,
}

impl SectionEdit {
    /// The plane: `n · x − position > 0` is cut away (or `< 0`, flipped).
    pub fn plane(&self) -> Option<SectionPlane> {
        if !self.enabled {
            return None;
        }
        let mut normal = match self.axis {
            0 => [1.0, 0.0, 0.0],
            1 => [0.0, 1.0, 0.0],
            2 => [0.0, 0.0, 1.0],
            _ => self.normal,
        };
        let mut offset = -self.position;
        if self.flipped {
            normal = normal.map(|v| -v);
            offset = -offset;
        }
        Some(SectionPlane { normal, offset })
    }

    /// The edit of a plane given on the command line (normalised there).
    pub fn of(plane: SectionPlane) -> SectionEdit {
        SectionEdit {
            enabled: true,
            axis: 3,
            normal: plane.normal,
            position: -plane.offset,
            flipped: false,
        }
    }
}

/// Everything the review window shows and edits.
pub struct Review {
    /// The parts and which are hidden or picked.
    pub parts: Parts,
    /// The search text.
    pub search: String,
    /// The last pick: where it hit (none: the background).
    pub pick: Option<Hit>,
    /// Clicks measure instead of pick.
    pub measuring: bool,
    /// The first end of a measurement in progress (snapped).
    pub measure_from: Option<NearestLeaf>,
    /// The last finished measurement.
    pub measurement: Option<Measurement>,
    /// The section planes.
    pub sections: [SectionEdit; MAX_SECTIONS],
    /// The model's bounds along x, y and z (the section sliders' ranges).
    pub bounds: [[f32; 2]; 3],
    looks_changed: bool,
}

impl Review {
    /// The review of `parts`, with sections from the command line, in a model of `bounds`.
    pub fn new(
        parts: Parts,
        sections: [Option<SectionPlane>; MAX_SECTIONS],
        bounds: [[f32; 2]; 3],
    ) -> Review {
        Review {
            parts,
            search: String::new(),
            pick: None,
            measuring: false,
            measure_from: None,
            measurement: None,
            sections: std::array::from_fn(|k| match sections[k] {
                Some(plane) => SectionEdit::of(plane),
                None => SectionEdit {
                    enabled: false,
                    axis: k,
                    normal: [0.0; 3],
                    position: (bounds[k][0] + bounds[k][1]) / 2.0,
                    flipped: false,
                },
            }),
            bounds,
            looks_changed: true,
        }
    }

    /// The planes that clip now.
    pub fn planes(&self) -> [Option<SectionPlane>; MAX_SECTIONS] {
        self.sections.map(|s| s.plane())
    }

    /// True once after anything changed what the parts look like.
    pub fn take_looks_changed(&mut self) -> bool {
        std::mem::take(&mut self.looks_changed)
    }

    /// A click picked `hit`.
    pub fn picked(&mut self, hit: Option<Hit>) {
        self.pick = hit;
        self.parts.picked = hit.map(|h| h.part);
        self.looks_changed = true;
    }

    /// A click in measuring mode snapped to `vertex` (none: it hit the background): the
    /// first end, or the second, which finishes the measurement.
    pub fn measured(&mut self, vertex: Option<NearestLeaf>) {
        match (self.measure_from, vertex) {
            (Some(a), Some(b)) => {
                self.measurement = Some(Measurement::between(a, b));
                self.measure_from = None;
            }
            _ => self.measure_from = vertex,
        }
    }

    fn hide(&mut self, id: u32, hidden: bool) {
        self.parts.set_hidden(id, hidden);
        self.looks_changed = true;
    }

    /// Lays the review window out.
    pub fn show(&mut self, ctx: &egui::Context) {
        egui::Window::new("review")
            .default_pos([12.0, 420.0])
            .default_width(300.0)
            .show(ctx, |ui| {
                self.picked_ui(ui);
                ui.separator();
                self.measure_ui(ui);
                ui.separator();
                self.sections_ui(ui);
                ui.separator();
                self.tree_ui(ui);
            });
    }

    fn picked_ui(&mut self, ui: &mut egui::Ui) {
        match self.pick {
            Some(hit) => {
                let part = self.parts.parts.get(hit.part as usize);
                ui.label(format!(
                    "picked: {}",
                    part.map_or_else(|| format!("part {}", hit.part), |p| p.name.clone())
                ));
                if let Some(part) = part {
                    ui.monospace(&part.path);
                    ui.label(format!("{} triangles", part.triangles));
                }
                let [x, y, z] = hit.world;
                ui.monospace(format!("at ({x:.4}, {y:.4}, {z:.4})"));
                ui.horizontal(|ui| {
                    if ui.button("hide").clicked() {
                        self.hide(hit.part, true);
                    }
                    if ui.button("isolate").clicked() {
                        self.parts.isolate(&[hit.part]);
                        self.looks_changed = true;
                    }
                    if ui.button("show all").clicked() {
                        self.parts.show_all();
                        self.looks_changed = true;
                    }
                });
            }
            None => {
                ui.label("click a part to pick it (H hide, I isolate, U show all)");
                if ui.button("show all").clicked() {
                    self.parts.show_all();
                    self.looks_changed = true;
                }
            }
        }
    }

    fn measure_ui(&mut self, ui: &mut egui::Ui) {
        ui.checkbox(&mut self.measuring, "measure: click two points (M)");
        if let Some(from) = self.measure_from {
            let [x, y, z] = from.position;
            ui.monospace(format!(
                "from ({x:.4}, {y:.4}, {z:.4}); click the second point"
            ));
        }
        if let Some(m) = self.measurement {
            ui.monospace(format!("distance {:.6}", m.distance));
            for end in m.ends {
                let [x, y, z] = end.position;
                ui.monospace(format!(
                    "  vertex ({x:.4}, {y:.4}, {z:.4}){}",
                    if end.exact { "" } else { " (nearest found)" }
                ));
            }
        }
    }

    fn sections_ui(&mut self, ui: &mut egui::Ui) {
        ui.label("sections (K: first on/off, [ ] move it)");
        let bounds = self.bounds;
        for (k, section) in self.sections.iter_mut().enumerate() {
            ui.horizontal(|ui| {
                ui.checkbox(&mut section.enabled, format!("{}", k + 1));
                egui::ComboBox::from_id_salt(("section axis", k))
                    .width(60.0)
                    .selected_text(["x", "y", "z", "given"][section.axis])
                    .show_ui(ui, |ui| {
                        for (a, name) in ["x", "y", "z"].iter().enumerate() {
                            ui.selectable_value(&mut section.axis, a, *name);
                        }
                        if section.normal != [0.0; 3] {
                            ui.selectable_value(&mut section.axis, 3, "given");
                        }
                    });
                let range = if section.axis < 3 {
                    bounds[section.axis]
                } else {
                    // Along a given normal: the bounds' extent on the longest axis.
                    let extent = (0..3)
                        .map(|a| bounds[a][1] - bounds[a][0])
                        .fold(0.0f32, f32::max);
                    [section.position - extent, section.position + extent]
                };
                ui.add(egui::Slider::new(
                    &mut section.position,
                    range[0]..=range[1],
                ));
                ui.checkbox(&mut section.flipped, "flip");
            });
        }
    }

    fn tree_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label("parts");
            ui.text_edit_singleline(&mut self.search);
        });
        egui::ScrollArea::vertical()
            .max_height(320.0)
            .show(ui, |ui| {
                if self.search.is_empty() {
                    let mut rows = 0;
                    let top = self.parts.children(None).to_vec();
                    for id in top {
                        self.node_ui(ui, id, &mut rows);
                    }
                } else {
                    let needle = self.search.to_lowercase();
                    let found: Vec<u32> = (0..self.parts.len() as u32)
                        .filter(|&id| {
                            self.parts.parts[id as usize]
                                .path
                                .to_lowercase()
                                .contains(&needle)
                        })
                        .take(MAX_ROWS)
                        .collect();
                    for id in found {
                        self.row_ui(ui, id, true);
                    }
                }
            });
    }

    /// One tree row: a checkbox (shown) and the name, the picked part in bold.
    fn row_ui(&mut self, ui: &mut egui::Ui, id: u32, full_path: bool) {
        ui.horizontal(|ui| {
            let mut shown = !self.parts.hidden[id as usize];
            if ui.checkbox(&mut shown, "").changed() {
                self.hide(id, !shown);
            }
            let part = &self.parts.parts[id as usize];
            let name = if full_path { &part.path } else { &part.name };
            let text = egui::RichText::new(name);
            let text = if self.parts.picked == Some(id) {
                text.strong()
            } else {
                text
            };
            if ui
                .selectable_label(self.parts.picked == Some(id), text)
                .clicked()
            {
                self.pick = None;
                self.parts.picked = Some(id);
                self.looks_changed = true;
            }
        });
    }

    fn node_ui(&mut self, ui: &mut egui::Ui, id: u32, rows: &mut usize) {
        *rows += 1;
        if *rows > MAX_ROWS {
            if *rows == MAX_ROWS + 1 {
                ui.label("… (search to narrow)");
            }
            return;
        }
        let children = self.parts.children(Some(id)).to_vec();
        if children.is_empty() {
            self.row_ui(ui, id, false);
            return;
        }
        let name = self.parts.parts[id as usize].name.clone();
        ui.horizontal(|ui| {
            let mut shown = !self.parts.hidden[id as usize];
            if ui.checkbox(&mut shown, "").changed() {
                self.hide(id, !shown);
            }
            egui::CollapsingHeader::new(name)
                .id_salt(("part", id))
                .show(ui, |ui| {
                    for child in children {
                        self.node_ui(ui, child, rows);
                    }
                });
        });
    }

    /// Hides the picked part (key H).
    pub fn hide_picked(&mut self) {
        if let Some(id) = self.parts.picked {
            self.hide(id, true);
        }
    }

    /// Shows only the picked part (key I).
    pub fn isolate_picked(&mut self) {
        if let Some(id) = self.parts.picked {
            self.parts.isolate(&[id]);
            self.looks_changed = true;
        }
    }

    /// Shows every part (key U).
    pub fn show_all(&mut self) {
        self.parts.show_all();
        self.looks_changed = true;
    }

    /// Turns the first section on or off (key K).
    pub fn toggle_first_section(&mut self) {
        self.sections[0].enabled = !self.sections[0].enabled;
    }

    /// Moves the first section by `fraction` of the model's extent along its axis (keys
    /// `[` and `]`).
    pub fn move_first_section(&mut self, fraction: f32) {
        let section = &mut self.sections[0];
        let axis = section.axis.min(2);
        let extent = self.bounds[axis][1] - self.bounds[axis][0];
        section.position += fraction * extent;
    }
}
