//! The variable-size metadata section, encoded with `rkyv` and validated (bytecheck) when
//! read, then checked field by field ([`Metadata::check`]): part parents in range and before
//! their children, colours finite and within 0..=1. Nothing here depends on the clock or the
//! machine, so identical inputs and options give identical bytes.

/// [`PartInfo::parent`] of a part at the top of the assembly.
pub const NO_PART: u32 = u32::MAX;

/// The most parts a file may name: 2²⁴ ≈ 16.7 M, far more than any assembly has (importers
/// already stop at 256 MiB of names), and few enough that counting triangles per part
/// (`--verify`) takes at most 128 MiB whatever a page claims.
pub const MAX_PARTS: u64 = 1 << 24;

/// What a file knows of one part besides its name (`Metadata::part_names` holds the names).
#[derive(Debug, Clone, Copy, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct PartInfo {
    /// The part this one belongs to in the assembly, or [`NO_PART`]. Always below the part's
    /// own index, so the parents form a forest.
    pub parent: u32,
    /// RGBA, each component in `0.0..=1.0`, as the input states it (glTF's linear
    /// `baseColorFactor`, OBJ's `Kd`, PLY and STL colours scaled from their integers), when
    /// it states one; `docs/format.md` says where each importer takes it from.
    pub color: Option<[f32; 4]>,
    /// How many of the file's triangles carry this part's id.
    pub triangles: u64,
}

impl Default for PartInfo {
    fn default() -> Self {
        PartInfo {
            parent: NO_PART,
            color: None,
            triangles: 0,
        }
    }
}

/// One input file the tree was built from.
#[derive(Debug, Clone, PartialEq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct InputInfo {
    /// The file's name, without its directories (so that the same input gives the same bytes
    /// however it was spelt and wherever the build ran; [`InputInfo::content_hash`] says which
    /// file it was).
    pub name: String,
    /// Its size in bytes.
    pub bytes: u64,
    /// XXH3-64 of its contents.
    pub content_hash: u64,
}

/// The options the tree was built with.
#[derive(Debug, Clone, PartialEq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct BuildInfo {
    /// Relative weld tolerance, if any (exact welding otherwise).
    pub weld: Option<f32>,
    /// zstd level of the pages.
    pub zstd_level: i32,
    /// Target raw bytes per page.
    pub page_bytes: u32,
}

/// Everything about a tree that is not a fixed-size record.
#[derive(Debug, Clone, PartialEq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct Metadata {
    /// The writing tool and its version, e.g. `vds-build 0.1.0`.
    pub tool: String,
    /// Build options.
    pub build: BuildInfo,
    /// Input files, in order.
    pub inputs: Vec<InputInfo>,
    /// Part names; triangles refer to them by index.
    pub part_names: Vec<String>,
    /// One entry per part name, or none at all (a file that states nothing about its parts
    /// beyond their names: every part at the top, uncoloured, triangle counts unknown).
    pub parts: Vec<PartInfo>,
    /// Lower corner of the bounding box of all vertices.
    pub bounds_min: [f32; 3],
    /// Upper corner.
    pub bounds_max: [f32; 3],
    /// Vertices as read, before welding.
    pub input_vertices: u64,
    /// Triangles as read, before dropping degenerate ones.
    pub input_triangles: u64,
    /// Number of nodes with k children, k = 0..=8.
    pub degree_histogram: [u64; 9],
}

impl Metadata {
    /// Checks what bytecheck cannot: at most [`MAX_PARTS`] parts, `parts` empty or one per
    /// name, every parent [`NO_PART`] or below its part's index (so no part is its own
    /// ancestor), every colour component finite and within `0.0..=1.0`, and the per-part
    /// triangle counts adding up to `triangle_count` (the header's).
    ///
    /// # Errors
    /// The first violation, naming the part.
    pub fn check(&self, triangle_count: u64) -> Result<(), crate::VdtError> {
        use crate::VdtError;
        if self.part_names.len() as u64 > MAX_PARTS {
            return Err(VdtError::invalid(
                "metadata",
                format!(
                    "{} part names, more than the {MAX_PARTS} a file may have",
                    self.part_names.len()
                ),
            ));
        }
        if self.parts.is_empty() {
            return Ok(());
        }
        if self.parts.len() != self.part_names.len() {
            return Err(VdtError::invalid(
                "metadata",
                format!(
                    "{} part records for {} part names (there must be one per name, or none)",
                    self.parts.len(),
                    self.part_names.len()
                ),
            ));
        }
        let mut triangles = 0u64;
        for (index, part) in self.parts.iter().enumerate() {
            let what = || format!("metadata part {index}");
            if part.parent != NO_PART && part.parent as usize >= index {
                return Err(VdtError::invalid(
                    what(),
                    format!(
                        "parent {} is not an earlier part (parents precede their children, \
                         which rules out cycles)",
                        part.parent
                    ),
                ));
            }
            if let Some(color) = part.color
                && !color.iter().all(|c| (0.0..=1.0).contains(c))
            {
                return Err(VdtError::invalid(
                    what(),
                    format!("colour {color:?} is not four components within 0..=1"),
                ));
            }
            triangles = triangles.checked_add(part.triangles).ok_or_else(|| {
                VdtError::invalid(what(), "triangle counts overflow a 64-bit sum")
            })?;
        }
        if triangles != triangle_count {
            return Err(VdtError::invalid(
                "metadata",
                format!(
                    "the parts' triangle counts add up to {triangles}, the file holds \
                     {triangle_count} triangles"
                ),
            ));
        }
        Ok(())
    }

    /// The parent of part `index`, if it has one (none also when the file states no parents
    /// or `index` is out of range).
    pub fn part_parent(&self, index: usize) -> Option<u32> {
        self.parts
            .get(index)
            .map(|p| p.parent)
            .filter(|&p| p != NO_PART)
    }

    /// The colour of part `index`, if the file gives one.
    pub fn part_color(&self, index: usize) -> Option<[f32; 4]> {
        self.parts.get(index).and_then(|p| p.color)
    }

    /// The names from the top of the assembly down to part `index`, joined by `/`
    /// (`Engine/Block/Bolt_12`); the name alone for a part at the top. Empty for an index
    /// out of range.
    pub fn part_path(&self, index: usize) -> String {
        let mut chain = Vec::new();
        let mut at = Some(index);
        // Parents are below their children (checked on open), so this ends.
        while let Some(i) = at {
            let Some(name) = self.part_names.get(i) else {
                break;
            };
            chain.push(name.as_str());
            at = self.part_parent(i).map(|p| p as usize).filter(|&p| p < i);
        }
        chain.reverse();
        chain.join("/")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three parts, `b` under `a`; 5 triangles in all.
    fn metadata() -> Metadata {
        Metadata {
            part_names: vec!["a".into(), "b".into(), "c".into()],
            parts: vec![
                PartInfo {
                    color: Some([1.0, 0.5, 0.0, 1.0]),
                    triangles: 2,
                    ..Default::default()
                },
                PartInfo {
                    parent: 0,
                    triangles: 3,
                    ..Default::default()
                },
                PartInfo::default(),
            ],
            ..Default::default()
        }
    }

    fn refusal(m: &Metadata, triangles: u64) -> String {
        m.check(triangles).unwrap_err().to_string()
    }

    #[test]
    fn accepts_a_forest_of_parts_and_no_part_records() {
        metadata().check(5).unwrap();
        let names_only = Metadata {
            parts: Vec::new(),
            ..metadata()
        };
        names_only.check(5).unwrap();
    }

    #[test]
    fn rejects_a_parent_out_of_range() {
        let mut m = metadata();
        m.parts[1].parent = 7;
        assert!(refusal(&m, 5).contains("part 1: parent 7"));
    }

    #[test]
    fn rejects_a_cycle_as_a_parent_not_before_its_child() {
        let mut m = metadata();
        // 0 -> 1 -> 0: part 0's parent comes after it.
        m.parts[0].parent = 1;
        assert!(refusal(&m, 5).contains("part 0: parent 1"));
        let mut m = metadata();
        m.parts[2].parent = 2;
        assert!(refusal(&m, 5).contains("part 2: parent 2"));
    }

    #[test]
    fn rejects_colours_outside_zero_to_one_or_not_finite() {
        for bad in [f32::NAN, f32::INFINITY, -0.1, 1.5] {
            let mut m = metadata();
            m.parts[0].color = Some([0.0, bad, 0.0, 1.0]);
            assert!(refusal(&m, 5).contains("colour"), "{bad}");
        }
    }

    #[test]
    fn rejects_part_records_not_one_per_name() {
        let mut m = metadata();
        m.parts.pop();
        assert!(refusal(&m, 5).contains("2 part records for 3 part names"));
    }

    #[test]
    fn rejects_triangle_counts_that_miss_the_file_total() {
        assert!(refusal(&metadata(), 6).contains("add up to 5"));
        let mut m = metadata();
        m.parts[2].triangles = u64::MAX;
        assert!(refusal(&m, 5).contains("overflow"));
    }

    #[test]
    fn part_paths_join_the_names_down_the_tree() {
        let m = metadata();
        assert_eq!(m.part_path(1), "a/b");
        assert_eq!(m.part_path(2), "c");
        assert_eq!(m.part_path(9), "");
        assert_eq!(m.part_parent(0), None);
        assert_eq!(m.part_parent(1), Some(0));
        assert_eq!(m.part_color(0), Some([1.0, 0.5, 0.0, 1.0]));
    }
}
