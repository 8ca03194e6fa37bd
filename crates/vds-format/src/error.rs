//! Errors of reading and writing `.vdt` files. Reading treats every file as hostile: each
//! variant says what was wrong and where, so a user can tell a truncated download from a
//! file of a newer version.

use std::path::PathBuf;

/// A `.vdt` file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum VdtError {
    /// The operating system refused.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        cause: std::io::Error,
    },
    /// The path names a FIFO, a device or a directory (itself or through a link), which is
    /// never read: it could block or never end.
    #[error("{path}: not a regular file; only regular files are read")]
    NotAFile {
        /// The path.
        path: PathBuf,
    },
    /// Not a `.vdt` file.
    #[error("not a .vdt file (bad magic bytes)")]
    Magic,
    /// A version this reader does not read: older files must be rebuilt from their inputs
    /// with `vds-build`, newer ones need a newer reader.
    #[error(
        "the file is .vdt version {got}, this reader reads {}; rebuild it from its inputs with this vds-build (or use a newer reader)",
        version_range(*.oldest, *.expected)
    )]
    Version {
        /// The newest version this reader reads.
        expected: u32,
        /// The oldest version this reader reads ([`crate::OLDEST_READABLE_VERSION`]).
        oldest: u32,
        /// What the file says.
        got: u32,
    },
    /// The file is shorter than its own offsets say.
    #[error("{what}: needs bytes up to {needed}, file has {available}")]
    Truncated {
        /// Which part of the file.
        what: String,
        /// The end offset it needs.
        needed: u64,
        /// The file size.
        available: u64,
    },
    /// A checksum does not match.
    #[error("{what}: checksum mismatch (stored {expected:#018x}, computed {got:#018x})")]
    Checksum {
        /// Which part of the file.
        what: String,
        /// Stored.
        expected: u64,
        /// Computed.
        got: u64,
    },
    /// A field has an impossible value.
    #[error("{what}: {message}")]
    Invalid {
        /// Which part of the file.
        what: String,
        /// What is wrong.
        message: String,
    },
    /// A figure the header or metadata states is not what the pages hold (found by
    /// [`crate::VdtFile::check_figures`], which `--verify` runs after decoding every page).
    #[error("{field} states {stated}, but the pages hold {counted}{}", field.bound_note())]
    Misstated {
        /// The false figure.
        field: crate::StatedField,
        /// What the file states.
        stated: u64,
        /// What the pages hold.
        counted: u64,
    },
    /// A node's bounds contradict its parent's, found where the runtime first relies on
    /// them (when the parent unfolds and the node's page has loaded).
    #[error("page {page}, node {node}: {violation}")]
    Bounds {
        /// The page holding the node.
        page: u32,
        /// The node.
        node: u32,
        /// What is wrong.
        violation: BoundViolation,
    },
    /// An output file could not be written (or may not be: it is not a regular file).
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
    /// A page failed to decompress.
    #[error("page {page}: zstd: {message}")]
    Decompress {
        /// The page.
        page: u32,
        /// zstd's message.
        message: String,
    },
}

fn version_range(oldest: u32, newest: u32) -> String {
    if oldest == newest {
        format!("version {newest} only")
    } else {
        format!("versions {oldest} to {newest}")
    }
}

impl VdtError {
    /// An invalid-field error: `what` names the field or record, `message` what is wrong.
    pub fn invalid(what: impl Into<String>, message: impl Into<String>) -> VdtError {
        VdtError::Invalid {
            what: what.into(),
            message: message.into(),
        }
    }
}

/// How a node's decoded bounds contradict its parent's ([`VdtError::Bounds`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BoundViolation {
    /// The node's bounding sphere reaches past its parent's by more than the file's
    /// quantisation can explain. A parent's sphere holds every triangle its children's do, so
    /// one of the two is false.
    SphereOutsideParent {
        /// The parent.
        parent: u32,
        /// How far past (scene units).
        by: f32,
    },
    /// A leaf lies farther from its parent's proxy than the parent's error radius, which
    /// must hold every vertex under the parent.
    LeafOutsideErrorRadius {
        /// The parent.
        parent: u32,
        /// How far past (scene units).
        by: f32,
    },
}

impl std::fmt::Display for BoundViolation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            BoundViolation::SphereOutsideParent { parent, by } => write!(
                f,
                "bounding sphere reaches {by} past the sphere of its parent {parent}"
            ),
            BoundViolation::LeafOutsideErrorRadius { parent, by } => write!(
                f,
                "leaf lies {by} outside the error radius of its parent {parent}"
            ),
        }
    }
}
