//! Wavefront OBJ: a streaming parser of its own. Every object or group becomes a named part;
//! polygons are fan-triangulated; points, lines, texture coordinates and normals are
//! skipped.
//!
//! Why not a crate: `tobj` (what this reader used before) reads about 60 MB/s, allocates a
//! `String` per line and holds the whole model twice, once as its own arrays and once as
//! ours; it reports what went wrong but not on which line; and it cannot stop reading early
//! or read from a stream in bounded memory. The statements a mesh needs are few (`v`, `f`,
//! `o`, `g`, `usemtl`, `mtllib`), so the parser is short: one pass over each line's bytes,
//! numbers parsed with the standard library's correctly rounded `f32` parser. The tests hold
//! it to `tobj`'s reading of the same files (`reference.rs`, compiled for tests only).
//! Material libraries are still parsed by `tobj` ([`materials`]).
//!
//! What it reads, as `tobj` did:
//! - `v x y z [w | r g b]`: a position, divided by `w` when one is given (`w = 0` is an
//!   error); per-vertex colours are not read.
//! - `f a b c ...`: the vertex index of each corner (the part before any `/`), 1-based or
//!   negative (relative to the vertices so far). A face with fewer than three corners is
//!   counted in [`MeshSoup::short_faces_dropped`].
//! - `o NAME`, `g NAME`: a new part when faces follow; consecutive groups of the same name are
//!   one part. Faces before any name, or under an empty one, go to a part named after the
//!   file (`NAME#k`, the k-th part, when the file has several parts).
//! - `usemtl NAME` and `mtllib FILE`: the part's colour is the `Kd` (with `d` as alpha) of the
//!   materials its faces use, averaged over its triangles. Libraries are read only for a file
//!   read from disk ([`MaterialFiles`]), resolved like glTF URIs ([`crate::uri::resolve`]),
//!   at most [`materials::MAX_MTL_BYTES`] in all; one that cannot be read costs only colours.
//! - Each model (a run of faces between a group or material change) lists its vertices in
//!   the order its faces first use them, as `tobj` did, so welded scenes and the trees built
//!   from them are the same as before.
//!
//! Where it is stricter or more lenient than `tobj`: a face may refer only to vertices
//! defined before it (the OBJ specification's rule; `tobj` also accepted vertices defined
//! later in the same group); a non-finite or out-of-range position is an error only when a
//! face uses it, named by its `v` line; texture-coordinate and normal statements are not
//! checked; a line that is not UTF-8 is read with replacement characters (only names can
//! hold such bytes).
//!
//! Line endings: LF, CR LF, and old Mac CR-only files (decided by the first line break); a
//! UTF-8 byte-order mark is skipped. A line longer than [`MAX_LINE_BYTES`] is refused with
//! its number. [`read_obj_stream`] reads from any `Read` (a gzip stream) in chunks of
//! [`CHUNK_BYTES`], so the text is never in memory whole.

mod materials;
#[cfg(test)]
mod reference;
#[cfg(test)]
mod tests;

use std::cell::RefCell;
use std::io::Read;

pub use materials::MaterialFiles;

use crate::error::{FormatError, Location, Problem};
use crate::soup::{ColorSum, MeshSoup, check_position};
use materials::{Libraries, material_color};

/// The longest line accepted, in bytes. Real files stay far below it (a face with 10,000
/// corners written as `v/vt/vn` triples is about 200 KB); the limit bounds what one line can
/// make the reader hold.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// How many bytes [`read_obj_stream`] asks of its source at a time.
pub const CHUNK_BYTES: usize = 1 << 20;

/// Bytes of text per vertex and per triangle assumed by [`Parser::reserve_for`]: less than
/// any real file spends (the bunny: 29 bytes per `v` line, 39 per `f` line), so that the
/// reservation is rarely outgrown.
const BYTES_PER_VERTEX_GUESS: usize = 32;
const BYTES_PER_TRIANGLE_GUESS: usize = 16;

/// The most rows [`Parser::reserve_for`] reserves in one array (a larger file grows its arrays
/// past that as usual).
const MAX_RESERVED_ROWS: usize = 1 << 24;

/// The name of a group before any `o` or `g`, or of one without a name (as `tobj` calls it):
/// such parts are named after the file in the end.
const UNNAMED: &str = "unnamed_object";

const BYTE_ORDER_MARK: &[u8] = b"\xEF\xBB\xBF";

/// Reads an OBJ file's bytes into `soup`, one part per object or group, with colours from
/// the material libraries `materials` lets it read (none: no library is read).
pub fn read_obj(
    data: &[u8],
    default_name: &str,
    materials: Option<&MaterialFiles>,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let data = data.strip_prefix(BYTE_ORDER_MARK).unwrap_or(data);
    let mut parser = Parser::new(default_name, materials);
    parser.endings = Endings::of(data).unwrap_or(Endings::Lf);
    if !soup.spills() {
        parser.reserve_for(data.len(), soup);
        parser.feed(data, soup)?;
        parser.finish(soup);
        return Ok(());
    }
    // A soup that spills takes the text a piece of whole lines at a time (about
    // `CHUNK_BYTES`), as the stream reader does, and spills after each.
    let mut done = 0;
    while done < data.len() {
        let rest = &data[done..];
        let window = &rest[..rest.len().min(CHUNK_BYTES)];
        let end = match parser.endings.last_break(window) {
            _ if window.len() == rest.len() => rest.len(),
            Some(at) => at + 1,
            // A line longer than the window: up to its end (the parser refuses one too long).
            None => parser
                .endings
                .first_break(&rest[window.len()..])
                .map_or(rest.len(), |at| window.len() + at + 1),
        };
        parser.feed(&rest[..end], soup)?;
        done += end;
        soup.spill_now();
        soup.done_with_input(&data[..done]);
    }
    parser.finish(soup);
    Ok(())
}

/// What stops [`read_obj_stream`]: the source, or the text.
#[derive(Debug)]
pub enum StreamError {
    /// Reading the source failed (a corrupt gzip stream, an I/O error).
    Read(std::io::Error),
    /// The text is not a valid OBJ file.
    Format(FormatError),
}

impl From<FormatError> for StreamError {
    fn from(error: FormatError) -> Self {
        StreamError::Format(error)
    }
}

/// Reads OBJ text from `source` in chunks of [`CHUNK_BYTES`] into `soup`, as [`read_obj`]
/// reads it from memory: the text itself is never held whole, only the current chunk and
/// one unfinished line.
pub fn read_obj_stream(
    source: &mut dyn Read,
    default_name: &str,
    materials: Option<&MaterialFiles>,
    soup: &mut MeshSoup,
) -> Result<(), StreamError> {
    let mut parser = Parser::new(default_name, materials);
    let mut buffer: Vec<u8> = Vec::with_capacity(CHUNK_BYTES);
    let mut first = true;
    let mut endings = None;
    loop {
        let at_end = fill(source, &mut buffer, CHUNK_BYTES).map_err(StreamError::Read)?;
        let mut text = &buffer[..];
        if first {
            text = text.strip_prefix(BYTE_ORDER_MARK).unwrap_or(text);
            first = false;
        }
        if endings.is_none() {
            endings = Endings::of(text).or(at_end.then_some(Endings::Lf));
            parser.endings = endings.unwrap_or(Endings::Lf);
        }
        // Only whole lines go to the parser; the unfinished last one waits for more text.
        let complete = if at_end {
            text.len()
        } else if endings.is_some() {
            parser.endings.last_break(text).map_or(0, |at| at + 1)
        } else {
            0
        };
        if complete == 0 && !at_end && text.len() > MAX_LINE_BYTES {
            return Err(line_too_long(parser.line + 1, text.len()).into());
        }
        parser.feed(&text[..complete], soup)?;
        soup.spill_now();
        let consumed = buffer.len() - (text.len() - complete);
        buffer.drain(..consumed);
        if at_end {
            break;
        }
    }
    parser.finish(soup);
    Ok(())
}

/// Reads from `source` until `buffer` holds at least `chunk` more bytes or the source ends;
/// true at the end.
fn fill(source: &mut dyn Read, buffer: &mut Vec<u8>, chunk: usize) -> std::io::Result<bool> {
    let target = buffer.len() + chunk;
    while buffer.len() < target {
        let start = buffer.len();
        buffer.resize(target, 0);
        let read = loop {
            match source.read(&mut buffer[start..]) {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                other => break other,
            }
        };
        let read = match read {
            Ok(read) => read,
            Err(e) => {
                buffer.truncate(start);
                return Err(e);
            }
        };
        buffer.truncate(start + read);
        if read == 0 {
            return Ok(true);
        }
    }
    Ok(false)
}

fn line_too_long(line: u64, bytes: usize) -> FormatError {
    FormatError::new(
        Location::Line(line),
        Problem::LineTooLong {
            bytes: bytes as u64,
            limit: MAX_LINE_BYTES as u64,
        },
    )
}

/// How lines end in one file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Endings {
    /// LF (and CR LF: the CR is whitespace at the end of the line).
    Lf,
    /// Classic Mac OS: every CR ends a line, and so does an LF; a CR LF pair ends one.
    Cr,
}

impl Endings {
    /// The file's line endings, from its first line break (none yet: not known).
    fn of(text: &[u8]) -> Option<Endings> {
        let at = memchr::memchr2(b'\r', b'\n', text)?;
        // A CR as the last byte seen may be the start of a CR LF pair: not known yet.
        match (text[at], text.get(at + 1)) {
            (b'\n', _) | (b'\r', Some(b'\n')) => Some(Endings::Lf),
            (b'\r', Some(_)) => Some(Endings::Cr),
            _ => None,
        }
    }

    /// Where the first line break of `text` is.
    fn first_break(self, text: &[u8]) -> Option<usize> {
        match self {
            Endings::Lf => memchr::memchr(b'\n', text),
            Endings::Cr => memchr::memchr2(b'\r', b'\n', text),
        }
    }

    /// Where the last line break of `text` is.
    fn last_break(self, text: &[u8]) -> Option<usize> {
        match self {
            Endings::Lf => memchr::memrchr(b'\n', text),
            Endings::Cr => memchr::memrchr2(b'\r', b'\n', text),
        }
    }
}

/// One vertex as the faces of the current model see it: the model that last used it and
/// its index in the soup for that model.
#[derive(Clone, Copy, Default)]
struct Use {
    model: u32,
    index: u32,
}

/// A part this file started: its id in the soup, its name as written, and its colour.
struct Part {
    id: u32,
    written_name: String,
    color: ColorSum,
}

/// The reader's state between lines.
struct Parser<'m> {
    endings: Endings,
    /// Lines read so far (the number of the line being read, once it is counted).
    line: u64,
    /// A CR ended the text fed last: an LF starting the next text belongs to it.
    pending_cr: bool,
    default_name: String,
    /// Every position read, in file order.
    positions: Vec<[f32; 3]>,
    /// Per position, where the current model put it in the soup.
    uses: Vec<Use>,
    /// The `v` lines of positions that fail [`check_position`] (an error once a face uses
    /// one).
    bad_positions: rustc_hash::FxHashMap<u32, u64>,
    /// The current model: a run of faces with one name and one material (`tobj`'s unit),
    /// counted from 1 so that `Use::default()` belongs to none.
    model: u32,
    model_has_faces: bool,
    /// The part the current model's triangles go to, once it has one.
    model_part: Option<usize>,
    /// Triangles of the current model, for its share of the part's colour.
    model_triangles: u64,
    name: String,
    parts: Vec<Part>,
    material: Option<usize>,
    materials: Vec<tobj::Material>,
    material_ids: std::collections::HashMap<String, usize>,
    files: Option<&'m MaterialFiles<'m>>,
    libraries: RefCell<Libraries>,
    corners: Vec<u32>,
}

impl<'m> Parser<'m> {
    fn new(default_name: &str, files: Option<&'m MaterialFiles<'m>>) -> Self {
        Parser {
            endings: Endings::Lf,
            line: 0,
            pending_cr: false,
            default_name: default_name.to_string(),
            positions: Vec::new(),
            uses: Vec::new(),
            bad_positions: Default::default(),
            model: 1,
            model_has_faces: false,
            model_part: None,
            model_triangles: 0,
            name: UNNAMED.into(),
            parts: Vec::new(),
            material: None,
            materials: Vec::new(),
            material_ids: Default::default(),
            files,
            libraries: RefCell::default(),
            corners: Vec::new(),
        }
    }

    /// Reserves room for the vertices and triangles that `text_bytes` of text can be expected
    /// to hold, so that the arrays do not grow by doubling: each doubling maps and faults in
    /// fresh pages and copies the old ones, which in a new process (a build reading its input)
    /// costs more than parsing the same bytes (the bunny's read: 115 fewer page faults, 0.8 ms
    /// of 9). The guess is generous (a vertex per [`BYTES_PER_VERTEX_GUESS`] and a triangle
    /// per [`BYTES_PER_TRIANGLE_GUESS`] bytes, several times what real files hold) because
    /// reserved pages that are never written cost address space, not memory; it is capped,
    /// and only a hint: a reservation that fails is skipped, and arrays still grow past it.
    fn reserve_for(&mut self, text_bytes: usize, soup: &mut MeshSoup) {
        let vertices = (text_bytes / BYTES_PER_VERTEX_GUESS).min(MAX_RESERVED_ROWS);
        let triangles = (text_bytes / BYTES_PER_TRIANGLE_GUESS).min(MAX_RESERVED_ROWS);
        let _ = self.positions.try_reserve(vertices);
        let _ = self.uses.try_reserve(vertices);
        let _ = soup.positions.try_reserve(vertices);
        let _ = soup.triangles.try_reserve(triangles);
        let _ = soup.triangle_parts.try_reserve(triangles);
    }

    /// Reads the whole lines of `text` (the last one may lack its line break only at the end
    /// of the file).
    fn feed(&mut self, mut text: &[u8], soup: &mut MeshSoup) -> Result<(), FormatError> {
        if std::mem::take(&mut self.pending_cr) {
            text = text.strip_prefix(b"\n").unwrap_or(text);
        }
        while !text.is_empty() {
            let (line, rest) = match self.endings {
                Endings::Lf => match memchr::memchr(b'\n', text) {
                    Some(at) => (&text[..at], &text[at + 1..]),
                    None => (text, &text[text.len()..]),
                },
                Endings::Cr => match memchr::memchr2(b'\r', b'\n', text) {
                    Some(at) if text[at] == b'\r' => match text.get(at + 1) {
                        Some(b'\n') => (&text[..at], &text[at + 2..]),
                        Some(_) => (&text[..at], &text[at + 1..]),
                        None => {
                            self.pending_cr = true;
                            (&text[..at], &text[at + 1..])
                        }
                    },
                    Some(at) => (&text[..at], &text[at + 1..]),
                    None => (text, &text[text.len()..]),
                },
            };
            self.line += 1;
            if line.len() > MAX_LINE_BYTES {
                return Err(line_too_long(self.line, line.len()));
            }
            self.statement(line, soup)?;
            text = rest;
        }
        Ok(())
    }

    fn syntax(&self, message: impl Into<String>) -> FormatError {
        FormatError::syntax(Location::Line(self.line), message)
    }

    /// One line.
    fn statement(&mut self, line: &[u8], soup: &mut MeshSoup) -> Result<(), FormatError> {
        if line.is_ascii() {
            // Almost every line of every file is a plain `v` or `f`: read in one pass over
            // its bytes when it is (anything unusual goes the general way, which also words
            // the errors).
            match line {
                [b'v', b' ', rest @ ..] => {
                    if let Some(p) = plain_vertex(rest) {
                        return self.push_position(p);
                    }
                }
                [b'f', b' ', rest @ ..] => {
                    let mut corners = std::mem::take(&mut self.corners);
                    let plain = self.plain_face(rest, &mut corners);
                    let result = plain.then(|| self.push_face(&mut corners, soup));
                    self.corners = corners;
                    if let Some(result) = result {
                        self.model_has_faces = true;
                        return result;
                    }
                }
                _ => {}
            }
            // Split on ASCII whitespace, which is all the whitespace such a line can hold.
            self.words(line, &mut AsciiWords { rest: line }, soup)
        } else {
            // Words split on Unicode whitespace, as `str::split_whitespace` (and `tobj`) does.
            let text = String::from_utf8_lossy(line);
            let mut words = text.split_whitespace().map(str::as_bytes);
            self.words(text.as_bytes(), &mut words, soup)
        }
    }

    fn words<'a>(
        &mut self,
        line: &'a [u8],
        words: &mut impl Iterator<Item = &'a [u8]>,
        soup: &mut MeshSoup,
    ) -> Result<(), FormatError> {
        let Some(keyword) = words.next() else {
            return Ok(());
        };
        match keyword {
            b"v" => self.vertex(words),
            b"f" => self.face(words, soup),
            b"o" | b"g" => {
                if self.model_has_faces {
                    self.end_model();
                }
                self.name = rest_after(line, keyword);
                if self.name.is_empty() {
                    self.name = UNNAMED.into();
                }
                Ok(())
            }
            b"usemtl" => {
                let name = rest_after(line, keyword);
                if name.is_empty() {
                    return Err(self.syntax("`usemtl` without a material name"));
                }
                let material = self.material_ids.get(&name).copied();
                if material != self.material && self.model_has_faces {
                    self.end_model();
                }
                self.material = material;
                Ok(())
            }
            b"mtllib" => {
                if let Some(files) = self.files {
                    let name = rest_after(line, keyword);
                    let loaded = files.load(std::path::Path::new(&name), &self.libraries);
                    // A library that cannot be read or parsed costs only its colours.
                    if let Ok((materials, ids)) = loaded {
                        let offset = self.materials.len();
                        self.materials.extend(materials);
                        for (name, id) in ids {
                            self.material_ids.insert(name, id + offset);
                        }
                    }
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// `v x y z [w | r g b]`.
    fn vertex<'a>(
        &mut self,
        words: &mut impl Iterator<Item = &'a [u8]>,
    ) -> Result<(), FormatError> {
        let mut p = [0f32; 3];
        for c in &mut p {
            *c = words
                .next()
                .and_then(parse_f32)
                .ok_or_else(|| self.syntax("a `v` statement needs three numeric coordinates"))?;
        }
        match (words.next(), words.next(), words.next()) {
            (None, ..) => {}
            (Some(w), None, _) => {
                let w = parse_f32(w)
                    .ok_or_else(|| self.syntax("the `w` of a `v` statement is not a number"))?;
                if w == 0.0 {
                    return Err(self.syntax("a `v` statement has w = 0"));
                }
                p = p.map(|c| c / w);
            }
            (Some(_), Some(_), None) => {
                return Err(self.syntax("a `v` statement has five values"));
            }
            (Some(_), Some(_), Some(_)) => {
                // Three more are a colour, which the tree does not use.
                if words.next().is_some() {
                    return Err(self.syntax("a `v` statement has more than six values"));
                }
            }
        }
        self.push_position(p)
    }

    fn push_position(&mut self, p: [f32; 3]) -> Result<(), FormatError> {
        let index = u32::try_from(self.positions.len())
            .map_err(|_| self.syntax("more than 2^32 vertices"))?;
        if check_position(p).is_err() {
            self.bad_positions.insert(index, self.line);
        }
        self.positions.push(p);
        self.uses.push(Use::default());
        Ok(())
    }

    /// The corners of a face line made of plain corners (`7`, `-2`, `7/1/3`) that all refer
    /// to vertices read so far, as file indices in `corners`; false for anything else.
    #[inline]
    fn plain_face(&self, mut rest: &[u8], corners: &mut Vec<u32>) -> bool {
        corners.clear();
        loop {
            rest = skip_spaces(rest);
            if rest.is_empty() {
                return true;
            }
            // The digits are read in the pass that finds the word's end: `parse_index` on the
            // word would need the end first, a second pass over every corner.
            let (negative, digits) = match rest {
                [b'-', tail @ ..] => (true, tail),
                _ => (false, rest),
            };
            let mut value: i64 = 0;
            let mut length = 0;
            while let Some(&d) = digits.get(length) {
                if !d.is_ascii_digit() || length == 18 {
                    break;
                }
                value = value * 10 + i64::from(d - b'0');
                length += 1;
            }
            rest = &digits[length..];
            let written = if negative { -value } else { value };
            let Some(index) = self.resolve(written).filter(|_| (1..18).contains(&length)) else {
                return false;
            };
            corners.push(index);
            // Texture and normal indices are not read.
            if let [b'/', ..] = rest {
                let end = rest.iter().position(is_space).unwrap_or(rest.len());
                rest = &rest[end..];
            } else if !rest.first().is_none_or(is_space) {
                return false;
            }
        }
    }

    /// The file index of the vertex a face corner refers to as `written` (1-based, or
    /// negative: relative to the vertices read so far), if that vertex has been read.
    #[inline]
    fn resolve(&self, written: i64) -> Option<u32> {
        let count = self.positions.len() as i64;
        let index = if written < 0 {
            count + written
        } else {
            written - 1
        };
        (written != 0 && (0..count).contains(&index)).then_some(index as u32)
    }

    /// `f a b c ...`.
    fn face<'a>(
        &mut self,
        words: &mut impl Iterator<Item = &'a [u8]>,
        soup: &mut MeshSoup,
    ) -> Result<(), FormatError> {
        self.model_has_faces = true;
        let mut corners = std::mem::take(&mut self.corners);
        corners.clear();
        for word in words {
            let written = parse_index(word);
            let Some(written) = written else {
                self.corners = corners;
                return Err(self.syntax(format!(
                    "face corner `{}` has no vertex index",
                    String::from_utf8_lossy(word)
                )));
            };
            let Some(index) = self.resolve(written) else {
                self.corners = corners;
                return Err(FormatError::new(
                    Location::Line(self.line),
                    Problem::IndexOutOfRange {
                        index: written,
                        vertex_count: self.positions.len() as u64,
                    },
                ));
            };
            corners.push(index);
        }
        let result = self.push_face(&mut corners, soup);
        self.corners = corners;
        result
    }

    /// Puts a face's vertices (file indices in `corners`, replaced by soup indices) and
    /// triangles into the soup.
    fn push_face(&mut self, corners: &mut [u32], soup: &mut MeshSoup) -> Result<(), FormatError> {
        if corners.len() < 3 {
            soup.short_faces_dropped += 1;
            return Ok(());
        }
        let part = self.model_part(soup);
        for corner in corners.iter_mut() {
            let vertex = *corner as usize;
            let used = self.uses[vertex];
            *corner = if used.model == self.model {
                used.index
            } else {
                let bad = &self.bad_positions;
                let index = soup.push_vertex(self.positions[vertex], || {
                    Location::Line(bad.get(&(vertex as u32)).copied().unwrap_or(0))
                })?;
                self.uses[vertex] = Use {
                    model: self.model,
                    index,
                };
                index
            };
        }
        soup.push_polygon(self.parts[part].id, corners);
        self.model_triangles += corners.len() as u64 - 2;
        Ok(())
    }

    /// The part of the current model, started when a model's name differs from the last
    /// part's.
    fn model_part(&mut self, soup: &mut MeshSoup) -> usize {
        if let Some(part) = self.model_part {
            return part;
        }
        let part = match self.parts.last() {
            Some(last) if last.written_name == self.name => self.parts.len() - 1,
            _ => {
                // Unnamed parts get their final name at the end, when the count is known.
                let id = soup.begin_part(self.name.clone());
                self.parts.push(Part {
                    id,
                    written_name: self.name.clone(),
                    color: ColorSum::default(),
                });
                self.parts.len() - 1
            }
        };
        self.model_part = Some(part);
        part
    }

    /// Ends the current model: its triangles add its material's colour to its part, and the
    /// next model lists its vertices afresh.
    fn end_model(&mut self) {
        if let (Some(part), Some(rgba)) = (
            self.model_part,
            self.material
                .and_then(|m| self.materials.get(m))
                .and_then(material_color),
        ) {
            self.parts[part]
                .color
                .add_weighted(rgba, self.model_triangles);
        }
        self.model += 1;
        self.model_has_faces = false;
        self.model_part = None;
        self.model_triangles = 0;
    }

    /// After the last line: colours, the names of unnamed parts, and the warnings.
    fn finish(mut self, soup: &mut MeshSoup) {
        self.end_model();
        let several = self.parts.len() > 1;
        for (k, part) in self.parts.iter().enumerate() {
            let id = part.id as usize;
            soup.parts[id].color = part.color.mean();
            if part.written_name == UNNAMED {
                soup.part_names[id] = if several {
                    format!("{}#{k}", self.default_name)
                } else {
                    self.default_name.clone()
                };
            }
        }
        soup.warnings
            .extend(std::mem::take(&mut self.libraries.get_mut().warnings));
    }
}

/// Whether `b` separates words on an ASCII line (as `char::is_whitespace` has it).
#[inline]
fn is_space(b: &u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | 0x0B | 0x0C)
}

#[inline]
fn skip_spaces(text: &[u8]) -> &[u8] {
    let start = text.iter().position(|b| !is_space(b)).unwrap_or(text.len());
    &text[start..]
}

/// The position of a `v` line made of three plain numbers (after `v `), or none.
#[inline]
fn plain_vertex(rest: &[u8]) -> Option<[f32; 3]> {
    let mut p = [0f32; 3];
    let mut rest = rest;
    for c in &mut p {
        let (value, tail) = fast_f32(skip_spaces(rest))?;
        if !tail.first().is_none_or(is_space) {
            return None;
        }
        *c = value;
        rest = tail;
    }
    skip_spaces(rest).is_empty().then_some(p)
}

/// The words of an ASCII line: split on ASCII whitespace (space, tab, vertical tab, form
/// feed, CR), as `str::split_whitespace` splits such a line, without its Unicode tables.
struct AsciiWords<'a> {
    rest: &'a [u8],
}

impl<'a> Iterator for AsciiWords<'a> {
    type Item = &'a [u8];

    #[inline]
    fn next(&mut self) -> Option<&'a [u8]> {
        let start = self.rest.iter().position(|b| !is_space(b))?;
        let rest = &self.rest[start..];
        let end = rest.iter().position(is_space).unwrap_or(rest.len());
        self.rest = &rest[end..];
        Some(&rest[..end])
    }
}

/// The text after `keyword` on `line`, without surrounding whitespace (a name may hold
/// spaces).
fn rest_after(line: &[u8], keyword: &[u8]) -> String {
    let text = String::from_utf8_lossy(line);
    let text = text.trim_start();
    // `keyword` is the line's first word, so the trimmed text starts with it.
    let keyword = std::str::from_utf8(keyword).unwrap_or_default();
    text.strip_prefix(keyword)
        .unwrap_or(text)
        .trim()
        .to_string()
}

/// Powers of ten that `f64` holds exactly.
const EXACT_POWERS_OF_TEN: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// A number as Rust (and `tobj`) parse an `f32`, correctly rounded: decimal or exponent
/// notation, `inf`, `nan`.
///
/// Most coordinates are short decimals (`-0.0378297`, `12.5`), which take a fast path: at
/// most 15 significant digits `m` and a power of ten `e` with `|e| ≤ 22`, so that `m` and
/// `10^|e|` are exact in `f64` and one multiplication or division rounds `m·10^e` correctly
/// to `f64` (Clinger's fast path). Rounding that `f64` on to `f32` is correct too unless it
/// lies exactly halfway between two `f32` values (the decimal may lie just off the halfway
/// point on the other side); that case, and every other form, goes to the standard
/// library's parser.
#[inline]
fn parse_f32(word: &[u8]) -> Option<f32> {
    match fast_f32(word) {
        Some((value, [])) => Some(value),
        _ => std::str::from_utf8(word).ok()?.parse().ok(),
    }
}

/// The fast path of [`parse_f32`] on the start of `text`: the number and what follows it.
#[inline]
fn fast_f32(word: &[u8]) -> Option<(f32, &[u8])> {
    let (negative, mut rest) = match word.split_first()? {
        (b'-', rest) => (true, rest),
        (b'+', rest) => (false, rest),
        _ => (false, word),
    };
    let mut mantissa: u64 = 0;
    let mut digits = 0u32;
    let mut scale = 0i32;
    let mut any = false;
    while let [d @ b'0'..=b'9', tail @ ..] = rest {
        mantissa = mantissa * 10 + u64::from(d - b'0');
        digits += u32::from(mantissa != 0);
        any = true;
        rest = tail;
        if digits > 15 {
            return None;
        }
    }
    if let [b'.', tail @ ..] = rest {
        rest = tail;
        while let [d @ b'0'..=b'9', tail @ ..] = rest {
            mantissa = mantissa * 10 + u64::from(d - b'0');
            digits += u32::from(mantissa != 0);
            scale -= 1;
            any = true;
            rest = tail;
            if digits > 15 {
                return None;
            }
        }
    }
    if !any {
        return None;
    }
    if let [b'e' | b'E', tail @ ..] = rest {
        let (sign, mut exponent_digits) = match tail {
            [b'-', t @ ..] => (-1, t),
            [b'+', t @ ..] => (1, t),
            t => (1, t),
        };
        let mut exponent = 0i32;
        let mut seen = false;
        while let [d @ b'0'..=b'9', t @ ..] = exponent_digits {
            if exponent > 1000 {
                return None;
            }
            exponent = exponent * 10 + i32::from(d - b'0');
            seen = true;
            exponent_digits = t;
        }
        if !seen {
            return None;
        }
        scale += sign * exponent;
        rest = exponent_digits;
    }
    if scale.unsigned_abs() as usize >= EXACT_POWERS_OF_TEN.len() {
        return None;
    }
    let power = EXACT_POWERS_OF_TEN[scale.unsigned_abs() as usize];
    let value = if scale < 0 {
        mantissa as f64 / power
    } else {
        mantissa as f64 * power
    };
    // Halfway between two `f32` values: the low 29 of the 52 mantissa bits that `f32` drops
    // are exactly 1000…0. (Only for normal `f32` results: below, `f32` keeps fewer bits.)
    if value.to_bits() & ((1 << 29) - 1) == 1 << 28
        || (value != 0.0 && !(f64::from(f32::MIN_POSITIVE)..=f64::from(f32::MAX)).contains(&value))
    {
        return None;
    }
    let value = value as f32;
    Some((if negative { -value } else { value }, rest))
}

/// A face corner's vertex index (the text before any `/`): an optional sign and decimal
/// digits, within `i64`.
#[inline]
fn parse_index(word: &[u8]) -> Option<i64> {
    let (negative, digits) = match word.split_first()? {
        (b'-', rest) => (true, rest),
        (b'+', rest) => (false, rest),
        _ => (false, word),
    };
    let mut value: i64 = 0;
    let mut count = 0;
    for &d in digits {
        if d == b'/' {
            break;
        }
        if !d.is_ascii_digit() || count == 18 {
            return None;
        }
        value = value * 10 + i64::from(d - b'0');
        count += 1;
    }
    (count > 0).then_some(if negative { -value } else { value })
}
