//! OBJ material libraries (`mtllib`): which files one OBJ file may read, within what
//! budget, and the colour a material gives. The libraries themselves are parsed by `tobj`
//! (they are a few kilobytes; the geometry reader is [`super`]).

/// The most bytes of material libraries one OBJ file may make the reader load, all its
/// `mtllib` statements together: real libraries are a few kilobytes, and the limit bounds
/// what a file naming one huge library many times can cost.
pub const MAX_MTL_BYTES: u64 = 16 << 20;

/// The most `mtllib` statements of one OBJ file that are followed (each costs a file open).
const MAX_MTL_FILES: usize = 64;

/// Where an OBJ file read from disk may find its material libraries.
pub struct MaterialFiles<'a> {
    /// The OBJ file's folder.
    pub folder: &'a std::path::Path,
    /// Whether libraries may lie outside it (see [`crate::ImportOptions::allow_external_uris`]).
    pub allow_external: bool,
}

/// The material libraries one OBJ file has loaded so far: which, how many bytes, and what
/// could not be read.
#[derive(Default)]
pub(super) struct Libraries {
    pub(super) read: Vec<std::path::PathBuf>,
    pub(super) bytes: u64,
    pub(super) warnings: Vec<String>,
}

impl MaterialFiles<'_> {
    /// Loads one library for `tobj`, within the budget `loaded` keeps; a library that cannot
    /// be read is a warning and tobj's `OpenFileFailed`, which costs only colours.
    pub(super) fn load(
        &self,
        name: &std::path::Path,
        loaded: &std::cell::RefCell<Libraries>,
    ) -> tobj::MTLLoadResult {
        let mut loaded = loaded.borrow_mut();
        match self.read(name, &mut loaded) {
            Ok(Some(bytes)) => tobj::load_mtl_buf(&mut &bytes[..]),
            // Already merged (or over the statement limit): nothing more to add.
            Ok(None) => Ok((Vec::new(), Default::default())),
            Err(why) => {
                loaded.warnings.push(format!(
                    "material library {}: {why}; its materials give no colours",
                    name.display()
                ));
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    }

    /// The bytes of library `name`, or none when it was read before or the file names too
    /// many.
    fn read(
        &self,
        name: &std::path::Path,
        loaded: &mut Libraries,
    ) -> Result<Option<Vec<u8>>, String> {
        let name = name.to_str().ok_or("the name is not UTF-8")?;
        let path = crate::uri::resolve(name, Some(self.folder), self.allow_external)
            .map_err(|reason| format!("refused ({reason})"))?;
        if loaded.read.contains(&path) || loaded.read.len() >= MAX_MTL_FILES {
            return Ok(None);
        }
        loaded.read.push(path.clone());
        let inside = (!self.allow_external).then_some(self.folder);
        let file = crate::uri::open_buffer_file(&path, inside).map_err(|e| e.to_string())?;
        if loaded.bytes.saturating_add(file.size) > MAX_MTL_BYTES {
            return Err(format!(
                "the libraries of one file may hold at most {MAX_MTL_BYTES} bytes"
            ));
        }
        let bytes = file
            .read_prefix(MAX_MTL_BYTES - loaded.bytes)
            .map_err(|e| e.to_string())?;
        loaded.bytes += bytes.len() as u64;
        Ok(Some(bytes))
    }
}

/// A material's colour: `Kd` with `d` as alpha (1 without it); none without `Kd`.
pub(super) fn material_color(material: &tobj::Material) -> Option<[f64; 4]> {
    let [r, g, b] = material.diffuse?;
    let a = material.dissolve.unwrap_or(1.0);
    Some([r, g, b, a].map(f64::from))
}
