//! The model's parts as a design review sees them: names, assembly paths, colours, triangle
//! counts (from the `.vdt` metadata), and which are hidden or picked. It owns the per-part
//! look the renderer draws ([`vds_render::PartLook`]) and the name matching of `--hide` and
//! `--isolate`.

use anyhow::{Context, Result};
use vds_format::{Metadata, NO_PART};
use vds_render::PartLook;

/// One part of the assembly.
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// Its own name (an OBJ object, a glTF node, an STL solid).
    pub name: String,
    /// Names from the top of the assembly down to this part, joined by `/`.
    pub path: String,
    /// The part above it, if any.
    pub parent: Option<u32>,
    /// The colour the file gives it (linear RGB).
    pub colour: Option<[f32; 3]>,
    /// Triangles of the full-detail model that carry its id.
    pub triangles: u64,
    /// Nesting depth (0 at the top).
    pub depth: u32,
}

/// Every part, and the review's state of each.
#[derive(Debug, Clone, Default)]
pub struct Parts {
    /// By part id.
    pub parts: Vec<Part>,
    /// Hidden parts (by id): their triangles are not drawn at any level of detail.
    pub hidden: Vec<bool>,
    /// The picked part.
    pub picked: Option<u32>,
    /// Children of each part, and the top-level parts last (index `parts.len()`).
    children: Vec<Vec<u32>>,
}

impl Parts {
    /// The parts a file's metadata lists.
    pub fn of(metadata: &Metadata) -> Parts {
        let count = metadata.part_names.len();
        let mut parts: Vec<Part> = Vec::with_capacity(count);
        let mut children = vec![Vec::new(); count + 1];
        for (id, name) in metadata.part_names.iter().enumerate() {
            let info = metadata.parts.get(id).copied().unwrap_or_default();
            // The metadata check keeps parents below their child's id: the parent's path is
            // already known.
            let parent =
                (info.parent != NO_PART && (info.parent as usize) < id).then_some(info.parent);
            let (path, depth) = match parent {
                Some(p) => {
                    let above = &parts[p as usize];
                    (format!("{}/{name}", above.path), above.depth + 1)
                }
                None => (name.clone(), 0),
            };
            children[parent.map_or(count, |p| p as usize)].push(id as u32);
            parts.push(Part {
                name: name.clone(),
                path,
                parent,
                colour: info.color.map(|[r, g, b, _]| [r, g, b]),
                triangles: info.triangles,
                depth,
            });
        }
        Parts {
            hidden: vec![false; parts.len()],
            parts,
            picked: None,
            children,
        }
    }

    /// The parts directly below `id`, or the top-level parts for `None`.
    pub fn children(&self, id: Option<u32>) -> &[u32] {
        let index = id.map_or(self.parts.len(), |p| p as usize);
        self.children.get(index).map_or(&[], Vec::as_slice)
    }

    /// The renderer's per-part looks.
    pub fn looks(&self) -> Vec<PartLook> {
        self.parts
            .iter()
            .enumerate()
            .map(|(id, part)| PartLook {
                colour: part.colour,
                hidden: self.hidden[id],
                picked: self.picked == Some(id as u32),
            })
            .collect()
    }

    /// `id` and every part below it in the assembly.
    pub fn subtree(&self, id: u32) -> Vec<u32> {
        let mut out = vec![id];
        let mut k = 0;
        while k < out.len() {
            out.extend_from_slice(self.children(Some(out[k])));
            k += 1;
        }
        out
    }

    /// Hides or shows `id` and everything below it.
    pub fn set_hidden(&mut self, id: u32, hidden: bool) {
        for p in self.subtree(id) {
            self.hidden[p as usize] = hidden;
        }
    }

    /// Shows only `ids` and what lies below them (the parts above stay hidden: their own
    /// triangles are other parts').
    pub fn isolate(&mut self, ids: &[u32]) {
        self.hidden.fill(true);
        for &id in ids {
            self.set_hidden(id, false);
        }
    }

    /// Shows every part.
    pub fn show_all(&mut self) {
        self.hidden.fill(false);
    }

    /// The parts whose name or path matches the shell-style `glob` (`*`, `?`, `[...]`,
    /// `{a,b}`; `*` crosses `/`), case-sensitively.
    pub fn matching(&self, glob: &str) -> Result<Vec<u32>> {
        let matcher = globset::Glob::new(glob)
            .with_context(|| format!("the part name pattern {glob:?}"))?
            .compile_matcher();
        Ok(self
            .parts
            .iter()
            .enumerate()
            .filter(|(_, p)| matcher.is_match(&p.name) || matcher.is_match(&p.path))
            .map(|(id, _)| id as u32)
            .collect())
    }

    /// Number of parts.
    pub fn len(&self) -> usize {
        self.parts.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vds_format::PartInfo;

    fn assembly() -> Parts {
        let mut metadata = Metadata::default();
        let names = ["Engine", "Block", "Bolt_1", "Bolt_2", "Wheel"];
        let parents = [NO_PART, 0, 1, 1, NO_PART];
        metadata.part_names = names.iter().map(|n| n.to_string()).collect();
        metadata.parts = parents
            .iter()
            .map(|&parent| PartInfo {
                parent,
                color: None,
                triangles: 1,
            })
            .collect();
        Parts::of(&metadata)
    }

    #[test]
    fn paths_follow_the_hierarchy() {
        let parts = assembly();
        assert_eq!(parts.parts[3].path, "Engine/Block/Bolt_2");
        assert_eq!(parts.parts[3].depth, 2);
        assert_eq!(parts.children(None), &[0, 4]);
        assert_eq!(parts.subtree(1), vec![1, 2, 3]);
    }

    #[test]
    fn globs_match_names_and_paths() {
        let parts = assembly();
        assert_eq!(parts.matching("Bolt_*").unwrap(), vec![2, 3]);
        assert_eq!(parts.matching("Engine/Block").unwrap(), vec![1]);
        assert_eq!(parts.matching("Engine*").unwrap(), vec![0, 1, 2, 3]);
        assert!(parts.matching("[").is_err());
    }

    #[test]
    fn isolating_hides_everything_else() {
        let mut parts = assembly();
        parts.isolate(&[1]);
        assert_eq!(parts.hidden, vec![true, false, false, false, true]);
        parts.show_all();
        parts.set_hidden(1, true);
        assert_eq!(parts.hidden, vec![false, true, true, true, false]);
    }
}
