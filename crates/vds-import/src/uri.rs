//! Where a glTF file's URIs may lead: resolving a buffer URI to a file inside the model's
//! folder, and reading no more of it than the file says it needs.
//!
//! A model handed to a batch job must not make the job read other files: a buffer URI of
//! `/etc/passwd` or `../../secret.key` would turn that file's bytes into geometry (and into
//! a `.vdt` someone else may read). So by default a URI is percent-decoded, then refused if
//! it carries a scheme, is absolute, climbs out of the folder with `..`, or reaches outside
//! through a symbolic link. `allow_external` lifts the folder rule (and admits `file:` URIs);
//! other schemes are never fetched.

use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Resolves `uri` against `folder` (`None`: the bytes came without a folder, so no file may
/// be read), returning the file to read or why the URI is refused.
pub fn resolve(uri: &str, folder: Option<&Path>, allow_external: bool) -> Result<PathBuf, String> {
    let Some(folder) = folder else {
        return Err("the model was read from memory, so no file can be named".into());
    };
    let mut text = uri;
    if let Some(scheme) = scheme_of(uri) {
        if !(allow_external && scheme.eq_ignore_ascii_case("file")) {
            return Err(format!(
                "the scheme '{scheme}:' is not read (only data: URIs and relative paths)"
            ));
        }
        // file:///abs/path or file:/abs/path; a host part other than empty is refused.
        text = &uri[scheme.len() + 1..];
        if let Some(rest) = text.strip_prefix("//") {
            if !rest.starts_with('/') {
                return Err("a file: URI with a host is not read".into());
            }
            text = rest;
        }
    }
    let decoded = percent_decode(text)?;
    let relative = Path::new(&decoded);
    if relative.is_absolute() {
        return if allow_external {
            Ok(relative.to_path_buf())
        } else {
            Err("an absolute path leaves the model's folder".into())
        };
    }
    if allow_external {
        return Ok(folder.join(relative));
    }
    // Lexical normalisation: `a/../b` stays inside, `../b` does not.
    let mut inside = PathBuf::new();
    for component in relative.components() {
        match component {
            Component::Normal(part) => inside.push(part),
            Component::CurDir => {}
            Component::ParentDir => {
                if !inside.pop() {
                    return Err("'..' leaves the model's folder".into());
                }
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err("an absolute path leaves the model's folder".into());
            }
        }
    }
    if inside.as_os_str().is_empty() {
        return Err("the URI names the model's folder itself, not a file".into());
    }
    let file = folder.join(&inside);
    // A symbolic link inside the folder may still point out of it (checked again on the
    // opened file, see `open_buffer_file`, so a link swapped in between is caught).
    let real_folder = folder
        .canonicalize()
        .map_err(|e| format!("the model's folder cannot be resolved: {e}"))?;
    // Fail closed: a path that cannot be resolved (missing, a dangling link, a magic link
    // into /proc) is refused rather than opened.
    let real_file = file
        .canonicalize()
        .map_err(|e| format!("{} cannot be resolved: {e}", file.display()))?;
    if !real_file.starts_with(&real_folder) {
        return Err(format!(
            "it leads outside the model's folder, to {}",
            real_file.display()
        ));
    }
    Ok(file)
}

/// The scheme of an absolute URI (`http`, `file`, ...), per RFC 3986: a letter, then letters,
/// digits, `+`, `-` or `.`, then `:`. A one-letter "scheme" is a Windows drive (`C:`), which
/// is an absolute path and refused as such.
fn scheme_of(uri: &str) -> Option<&str> {
    let (scheme, _) = uri.split_once(':')?;
    let mut chars = scheme.chars();
    let first = chars.next()?;
    let valid = first.is_ascii_alphabetic()
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'));
    (valid && scheme.len() > 1).then_some(scheme)
}

/// Decodes `%XX` escapes (glTF URIs are RFC 3986 references); the result must be UTF-8 and
/// hold no NUL. A `%` not followed by two hex digits is refused rather than guessed at.
fn percent_decode(text: &str) -> Result<String, String> {
    let bytes = text.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = bytes
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("bad percent escape at byte {i}"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    if out.contains(&0) {
        return Err("the decoded path holds a NUL byte".into());
    }
    String::from_utf8(out).map_err(|_| "the decoded path is not UTF-8".into())
}

/// A regular file a URI names, opened, with what identifies it on its file system: two URIs
/// (or links) naming one file are read once, however many buffers name it.
pub struct BufferFile {
    file: std::fs::File,
    /// Device and inode on Unix (hard links and symbolic links resolve to one), else the
    /// canonical path.
    pub identity: (u64, u64, PathBuf),
    /// The file's size in bytes.
    pub size: u64,
}

/// Opens the regular file at `path` (see [`crate::source::open_regular_file`]). With
/// `inside`, the file opened must be the one `path` resolves to inside that folder, checked
/// after opening (device and inode of the open file against those of the canonical path):
/// a link swapped between [`resolve`]'s check and the open is refused, not followed.
pub fn open_buffer_file(path: &Path, inside: Option<&Path>) -> Result<BufferFile, String> {
    let file = crate::source::open_regular_file(path).map_err(|e| match e {
        crate::ImportError::Io { cause, .. } => cause.to_string(),
        other => other.to_string(),
    })?;
    let metadata = file.metadata().map_err(|e| e.to_string())?;
    #[cfg(unix)]
    let identity = {
        use std::os::unix::fs::MetadataExt;
        (metadata.dev(), metadata.ino(), PathBuf::new())
    };
    #[cfg(not(unix))]
    let identity = (0, 0, path.canonicalize().map_err(|e| e.to_string())?);
    if let Some(folder) = inside {
        let moved = || format!("{} changed while it was opened", path.display());
        let real_folder = folder.canonicalize().map_err(|_| moved())?;
        let real = path.canonicalize().map_err(|_| moved())?;
        if !real.starts_with(&real_folder) {
            return Err(format!(
                "it leads outside the model's folder, to {}",
                real.display()
            ));
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let now = std::fs::metadata(&real).map_err(|_| moved())?;
            if (now.dev(), now.ino()) != (identity.0, identity.1) {
                return Err(moved());
            }
        }
    }
    Ok(BufferFile {
        file,
        identity,
        size: metadata.len(),
    })
}

impl BufferFile {
    /// Reads at most `length` bytes from the start of the file: a buffer needs no more than
    /// its `byteLength`, and the allocation is never larger than the file.
    pub fn read_prefix(self, length: u64) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        // The file's size bounds the allocation; a sparse file of a terabyte is refused by
        // the caller's limit before this, and an allocation that still fails is an error.
        out.try_reserve_exact(length.min(self.size) as usize)
            .map_err(|e| e.to_string())?;
        // No further than the size the limits were checked against, even if the file grew.
        self.file
            .take(length.min(self.size))
            .read_to_end(&mut out)
            .map_err(|e| e.to_string())?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The folder must exist for the symbolic-link check; the files need not.
    fn inside(uri: &str) -> Result<PathBuf, String> {
        resolve(uri, Some(Path::new("/")), false)
    }

    #[test]
    fn relative_paths_resolve_inside_the_folder() {
        let folder = std::env::temp_dir().join(format!("vds-uri-{}", std::process::id()));
        std::fs::create_dir_all(folder.join("a")).unwrap();
        for name in ["hull.bin", "hull a.bin", "a/b.bin"] {
            std::fs::write(folder.join(name), b"x").unwrap();
        }
        let at = |uri| resolve(uri, Some(&folder), false);
        assert_eq!(at("hull.bin").unwrap(), folder.join("hull.bin"));
        assert_eq!(
            at("parts/../hull%20a.bin").unwrap(),
            folder.join("hull a.bin")
        );
        assert_eq!(at("./a/b.bin").unwrap(), folder.join("a/b.bin"));
        // A file that is not there is refused here, not opened later (fail closed).
        assert!(
            at("missing.bin")
                .unwrap_err()
                .contains("cannot be resolved")
        );
        std::fs::remove_dir_all(&folder).unwrap();
    }

    #[test]
    fn refuses_paths_that_leave_the_folder() {
        assert!(inside("/etc/passwd").unwrap_err().contains("absolute"));
        assert!(inside("../../../../etc/passwd").unwrap_err().contains(".."));
        assert!(inside("a/../../b.bin").unwrap_err().contains(".."));
        // Percent-encoding does not hide a climb or a root.
        assert!(inside("%2E%2E/secret").unwrap_err().contains(".."));
        assert!(inside("%2Fetc%2Fpasswd").unwrap_err().contains("absolute"));
    }

    #[test]
    fn refuses_schemes_and_bad_escapes() {
        assert!(
            inside("http://example.invalid/a.bin")
                .unwrap_err()
                .contains("scheme")
        );
        assert!(inside("file:///etc/passwd").unwrap_err().contains("scheme"));
        assert!(inside("a%2").unwrap_err().contains("escape"));
        assert!(inside("a%00b").unwrap_err().contains("NUL"));
        assert!(inside(".").is_err());
        assert!(resolve("a.bin", None, true).is_err());
    }

    #[test]
    fn allowing_external_uris_admits_absolute_and_file_paths() {
        let folder = Some(Path::new("/models/ship"));
        assert_eq!(
            resolve("/etc/x", folder, true).unwrap(),
            Path::new("/etc/x")
        );
        assert_eq!(
            resolve("file:///etc/x", folder, true).unwrap(),
            Path::new("/etc/x")
        );
        assert_eq!(
            resolve("../x", folder, true).unwrap(),
            Path::new("/models/ship/../x")
        );
        assert!(resolve("https://host/x", folder, true).is_err());
        assert!(resolve("file://host/x", folder, true).is_err());
    }
}
