//! The bundled demo: the CAx-IF AS1 assembly (`testdata/as1_assembly.obj`, 18 solids, see
//! `testdata/README.md`), embedded in the binary and given the assembly structure of the STEP
//! file it was tessellated from.
//!
//! The OBJ names its solids `solid_0` … `solid_17` and is flat. The STEP product structure
//! is: the assembly holds a plate, two L-bracket assemblies (an L-bracket and three nut-bolt
//! assemblies of a bolt and a nut each) and a rod assembly (a rod and two nuts). Which solid
//! is which was read off their shapes and places (bolts 15 × 15 × 37, nuts 20 × 15 × 3 under
//! the plate or 3 × 15 × 20 on the rod's ends, the 200-long rod, the 180 × 150 plate); the
//! table below writes that down, with a colour per kind of part.

use anyhow::{Result, anyhow};
use vds_import::{PartInfo, Scene};

/// The OBJ file.
const OBJ: &[u8] = include_bytes!("../../../testdata/as1_assembly.obj");

/// What the demo is called in messages and the window title.
pub const NAME: &str = "bundled demo (AS1 assembly)";

const STEEL: [f32; 4] = [0.55, 0.58, 0.62, 1.0];
const BRASS: [f32; 4] = [0.78, 0.57, 0.18, 1.0];
const BLUE: [f32; 4] = [0.16, 0.33, 0.62, 1.0];
const RED: [f32; 4] = [0.66, 0.16, 0.12, 1.0];
const GREEN: [f32; 4] = [0.22, 0.5, 0.3, 1.0];

/// Assembly nodes (no triangles of their own): name, parent index in this table.
const ASSEMBLIES: [(&str, Option<usize>); 10] = [
    ("as1", None),
    ("l-bracket-assembly 1", Some(0)),
    ("nut-bolt-assembly 1", Some(1)),
    ("nut-bolt-assembly 2", Some(1)),
    ("nut-bolt-assembly 3", Some(1)),
    ("l-bracket-assembly 2", Some(0)),
    ("nut-bolt-assembly 4", Some(5)),
    ("nut-bolt-assembly 5", Some(5)),
    ("nut-bolt-assembly 6", Some(5)),
    ("rod-assembly", Some(0)),
];

/// Per OBJ solid (`solid_K` is entry K): its name, the assembly it belongs to, its colour.
const SOLIDS: [(&str, usize, [f32; 4]); 18] = [
    ("nut 7", 9, BRASS),
    ("nut 8", 9, BRASS),
    ("rod", 9, GREEN),
    ("bolt 1", 2, STEEL),
    ("nut 1", 2, BRASS),
    ("bolt 2", 3, STEEL),
    ("nut 2", 3, BRASS),
    ("bolt 3", 4, STEEL),
    ("nut 3", 4, BRASS),
    ("l-bracket 1", 1, RED),
    ("plate", 0, BLUE),
    ("bolt 4", 6, STEEL),
    ("nut 4", 6, BRASS),
    ("bolt 5", 7, STEEL),
    ("nut 5", 7, BRASS),
    ("bolt 6", 8, STEEL),
    ("nut 6", 8, BRASS),
    ("l-bracket 2", 5, RED),
];

/// The demo scene, welded, with its assembly: the ten assembly nodes come first (parents
/// precede children, as the file format requires), then the solids.
pub fn scene() -> Result<Scene> {
    let mut soup = vds_import::MeshSoup::default();
    vds_import::read_bytes(OBJ, vds_import::Format::Obj, "as1", &mut soup)
        .map_err(|e| anyhow!("the bundled demo model: {e:?}"))?;
    let mut scene = vds_import::weld(soup, vds_import::Weld::Exact);
    let solid_of_part: Vec<usize> = scene
        .part_names
        .iter()
        .map(|name| {
            name.strip_prefix("solid_")
                .and_then(|k| k.parse::<usize>().ok())
                .filter(|&k| k < SOLIDS.len())
                .ok_or_else(|| anyhow!("the bundled demo has an unexpected part {name:?}"))
        })
        .collect::<Result<_>>()?;
    let offset = ASSEMBLIES.len() as u32;
    let mut names: Vec<String> = ASSEMBLIES.iter().map(|(n, _)| n.to_string()).collect();
    let mut parts: Vec<PartInfo> = ASSEMBLIES
        .iter()
        .map(|&(_, parent)| PartInfo {
            parent: parent.map(|p| p as u32),
            color: None,
        })
        .collect();
    for &solid in &solid_of_part {
        let (name, assembly, colour) = SOLIDS[solid];
        names.push(name.to_string());
        parts.push(PartInfo {
            parent: Some(assembly as u32),
            color: Some(colour),
        });
    }
    for part in &mut scene.triangle_parts {
        *part += offset;
    }
    scene.part_names = names;
    scene.parts = parts;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_solid_is_named_and_placed_once() {
        let scene = super::scene().unwrap();
        assert_eq!(scene.part_names.len(), 28);
        assert_eq!(scene.part_names[10 + 10], "plate");
        let mut names = scene.part_names.clone();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), 28, "names are unique");
        // Every assembly node holds something; every solid has triangles.
        for part in 0..28u32 {
            let has_children = scene.parts.iter().any(|p| p.parent == Some(part));
            let has_triangles = scene.triangle_parts.contains(&part);
            assert!(has_children != has_triangles, "part {part}");
        }
    }
}
