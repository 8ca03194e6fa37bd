//! Typed import errors: every failure names the file and, where the format allows, the line,
//! byte offset or element at fault.

use std::fmt;
use std::path::PathBuf;

/// Where in an input file a problem was found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    /// The whole file (no finer position is known).
    File,
    /// A 1-based line of a text file.
    Line(u64),
    /// A byte offset into a binary file.
    Byte(u64),
    /// The `index`-th (0-based) item of a named element, e.g. face 17 or mesh 2 / primitive 0.
    Element {
        /// What kind of item: `"vertex"`, `"face"`, `"triangle"`, `"mesh 2 primitive"`, ...
        kind: String,
        /// Its 0-based index.
        index: u64,
    },
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::File => write!(f, "file"),
            Location::Line(line) => write!(f, "line {line}"),
            Location::Byte(offset) => write!(f, "byte {offset}"),
            Location::Element { kind, index } => write!(f, "{kind} {index}"),
        }
    }
}

/// What is wrong with a malformed input.
#[derive(Debug, Clone, PartialEq)]
pub enum Problem {
    /// A coordinate is NaN or infinite.
    NonFiniteCoordinate,
    /// A face refers to a vertex that does not exist.
    IndexOutOfRange {
        /// The index as written (after resolving relative OBJ indices).
        index: i64,
        /// How many vertices there are.
        vertex_count: u64,
    },
    /// The file ends before the data its header promises.
    Truncated {
        /// Bytes needed from the location on.
        needed: u64,
        /// Bytes actually left.
        available: u64,
    },
    /// A count in the file cannot possibly fit in the bytes that follow it.
    CountExceedsFile {
        /// What is being counted.
        what: String,
        /// The count as written.
        count: u64,
        /// The most that the remaining bytes could hold.
        max_possible: u64,
    },
    /// A glTF primitive mode that has no triangles (points, lines).
    UnsupportedPrimitiveMode(String),
    /// A feature of the format that this importer does not read.
    Unsupported(String),
    /// The text or structure does not follow the format.
    Syntax(String),
    /// A coordinate is finite but so large that the tree's arithmetic could overflow.
    CoordinateOutOfRange {
        /// The coordinate as read (after any transform).
        value: f64,
        /// The largest magnitude accepted ([`crate::MAX_COORDINATE`]).
        limit: f64,
    },
    /// A text line is longer than any real file writes (a hostile or corrupt file).
    LineTooLong {
        /// The line's length in bytes.
        bytes: u64,
        /// The longest line accepted.
        limit: u64,
    },
    /// The input would grow past a limit of [`crate::ImportOptions`].
    LimitExceeded {
        /// What grew too large, e.g. "decompressed size" or "node 3 ('Bolt') expands to".
        what: String,
        /// How large it is (or at least how far it got before reading stopped).
        amount: u64,
        /// The limit.
        limit: u64,
        /// The command-line option that raises the limit (empty for a fixed limit).
        option: &'static str,
    },
    /// A glTF URI names something outside the model's folder, or a scheme other than `data:`.
    RefusedUri {
        /// The URI as written in the file.
        uri: String,
        /// Why it is refused.
        reason: String,
    },
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Problem::NonFiniteCoordinate => write!(f, "coordinate is NaN or infinite"),
            Problem::IndexOutOfRange {
                index,
                vertex_count,
            } => write!(
                f,
                "vertex index {index} is out of range (the file has {vertex_count} vertices)"
            ),
            Problem::Truncated { needed, available } => write!(
                f,
                "file is truncated: {needed} more bytes needed, {available} available"
            ),
            Problem::CountExceedsFile {
                what,
                count,
                max_possible,
            } => write!(
                f,
                "{what} count {count} exceeds what the file can hold (at most {max_possible})"
            ),
            Problem::UnsupportedPrimitiveMode(mode) => write!(
                f,
                "primitive mode {mode} has no triangles (only TRIANGLES, TRIANGLE_STRIP and \
                 TRIANGLE_FAN are supported)"
            ),
            Problem::Unsupported(what) => write!(f, "unsupported: {what}"),
            Problem::Syntax(what) => write!(f, "{what}"),
            Problem::CoordinateOutOfRange { value, limit } => write!(
                f,
                "coordinate {value:e} is out of range (at most {limit:e} in magnitude)"
            ),
            Problem::LineTooLong { bytes, limit } => write!(
                f,
                "line is {bytes} bytes long (at most {limit} are accepted)"
            ),
            Problem::LimitExceeded {
                what,
                amount,
                limit,
                option: "",
            } => write!(
                f,
                "{what} {amount}, more than the limit of {limit} (a fixed limit)"
            ),
            Problem::LimitExceeded {
                what,
                amount,
                limit,
                option,
            } => write!(
                f,
                "{what} {amount}, more than the limit of {limit} (raise it with {option})"
            ),
            Problem::RefusedUri { uri, reason } => write!(
                f,
                "URI '{uri}' is refused: {reason} (--allow-external-uris reads it anyway)"
            ),
        }
    }
}

/// An input could not be imported.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file (or a file it refers to, like a glTF `.bin`) could not be read.
    #[error("{path}: cannot read: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        cause: std::io::Error,
    },
    /// The file name does not end in a known mesh extension.
    #[error(
        "{path}: unknown mesh format (expected .obj, .gltf, .glb, .ply or .stl, optionally .gz)"
    )]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// The path names something that is not a regular file (a FIFO, a device, a directory),
    /// itself or through a symbolic link: reading it could block or never end.
    #[error("{path}: not a regular file ({kind}); only regular files are read")]
    NotAFile {
        /// The file.
        path: PathBuf,
        /// What it is instead.
        kind: &'static str,
    },
    /// The file was read but holds no triangle (only points, lines, or nothing).
    #[error("{path}: the file has no triangles (points and lines are ignored)")]
    NoTriangles {
        /// The file.
        path: PathBuf,
    },
    /// Every triangle of the inputs was degenerate after welding, so nothing is left to build.
    #[error("{}: no usable triangle: every triangle has two corners at the same welded vertex", display_paths(.paths))]
    NoUsableTriangles {
        /// The inputs.
        paths: Vec<PathBuf>,
    },
    /// The file's contents are malformed.
    #[error("{path}: {location}: {problem}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// Where in the file.
        location: Location,
        /// What is wrong.
        problem: Problem,
    },
}

fn display_paths(paths: &[PathBuf]) -> String {
    let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    names.join(", ")
}

impl ImportError {
    /// The problem, if this is a [`ImportError::Malformed`] error.
    pub fn problem(&self) -> Option<&Problem> {
        match self {
            ImportError::Malformed { problem, .. } => Some(problem),
            _ => None,
        }
    }
}

/// A malformed-input error before the file path is attached; format readers return this and
/// [`crate::load_file`] adds the path.
#[derive(Debug, Clone, PartialEq)]
pub struct FormatError {
    /// Where in the file.
    pub location: Location,
    /// What is wrong.
    pub problem: Problem,
}

impl FormatError {
    /// A problem at a location.
    pub fn new(location: Location, problem: Problem) -> Self {
        Self { location, problem }
    }

    /// A syntax problem at a location.
    pub fn syntax(location: Location, message: impl Into<String>) -> Self {
        Self::new(location, Problem::Syntax(message.into()))
    }

    /// A problem at the `index`-th item of kind `kind`.
    pub fn at_element(kind: &str, index: u64, problem: Problem) -> Self {
        Self::new(
            Location::Element {
                kind: kind.to_string(),
                index,
            },
            problem,
        )
    }

    /// Attaches the file path.
    pub fn in_file(self, path: impl Into<PathBuf>) -> ImportError {
        ImportError::Malformed {
            path: path.into(),
            location: self.location,
            problem: self.problem,
        }
    }
}
