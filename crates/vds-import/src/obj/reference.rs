//! The OBJ reader as it was before the streaming parser: `tobj` over prepared text. Kept
//! only for tests, which read files with both and compare the soups (the parser is
//! hand-written, so it is held to a well-used crate's reading of the same bytes).
//!
//! Before `tobj` sees the text, [`prepare`] skips a UTF-8 byte-order mark, turns old Mac
//! CR-only line endings into LF, and refuses any line longer than [`MAX_LINE_BYTES`].
//! [`ObjReader`] then hands `tobj` one line at a time, drops `l` (polyline) statements and
//! strips texture and normal indices from faces. `tobj` starts a new model where a group
//! switches material; consecutive models of the same name are one part.

use std::borrow::Cow;
use std::io::{BufRead, Read};

use super::MAX_LINE_BYTES;
use super::materials::{Libraries, MaterialFiles, material_color};
use crate::error::{FormatError, Location, Problem};
use crate::soup::MeshSoup;

/// The text `tobj` should see: no byte-order mark, LF line endings, no over-long line.
fn prepare(data: &[u8]) -> Result<Cow<'_, [u8]>, FormatError> {
    let data = data.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(data);
    // A file whose first line break is a lone CR uses CR line endings throughout (classic Mac
    // OS); CR LF and LF files are read as they are.
    let cr_only = memchr::memchr2(b'\r', b'\n', data)
        .is_some_and(|at| data[at] == b'\r' && data.get(at + 1) != Some(&b'\n'));
    let data: Cow<[u8]> = if cr_only {
        // Every CR ends a line; a CR LF pair later in the file ends one, not two.
        let mut text = Vec::with_capacity(data.len());
        for (i, &b) in data.iter().enumerate() {
            match b {
                b'\r' => text.push(b'\n'),
                b'\n' if i > 0 && data[i - 1] == b'\r' => {}
                _ => text.push(b),
            }
        }
        Cow::Owned(text)
    } else {
        Cow::Borrowed(data)
    };
    let mut line_start = 0;
    for (line, end) in memchr::memchr_iter(b'\n', &data)
        .chain(std::iter::once(data.len()))
        .enumerate()
    {
        if end - line_start > MAX_LINE_BYTES {
            return Err(FormatError::new(
                Location::Line(line as u64 + 1),
                Problem::LineTooLong {
                    bytes: (end - line_start) as u64,
                    limit: MAX_LINE_BYTES as u64,
                },
            ));
        }
        line_start = end + 1;
    }
    Ok(data)
}

/// A `BufRead` over the prepared text that hands `tobj` one line at a time, as `tobj` should
/// see it, and knows how far it got, so a parse error can be given a line number:
/// - `l` (polyline) statements are dropped;
/// - face corners lose their texture and normal indices (`f 1/2/3 4//5` becomes `f 1 4`):
///   the tree needs positions only, and `tobj` 4.0 panics on a relative texture or normal
///   index that points before the first one (`f 1/-5`) instead of reporting it.
struct ObjReader<'a> {
    data: &'a [u8],
    /// Where the line after the one being handed out starts.
    position: usize,
    /// The line being handed out, as `tobj` sees it (buffer reused from line to line).
    line: Vec<u8>,
    /// How much of `line` `tobj` has consumed.
    consumed: usize,
}

impl<'a> ObjReader<'a> {
    fn new(data: &'a [u8]) -> Self {
        ObjReader {
            data,
            position: 0,
            line: Vec::new(),
            consumed: 0,
        }
    }

    /// The 1-based number of the line that was read last.
    fn current_line(&self) -> u64 {
        let consumed = &self.data[..self.position];
        let newlines = memchr::memchr_iter(b'\n', consumed).count() as u64;
        // A handed-out line ends with its newline, so the line being parsed is the last
        // newline-terminated one; a final line without a newline adds one.
        let partial = u64::from(consumed.last().is_some_and(|&b| b != b'\n'));
        (newlines + partial).max(1)
    }

    /// Moves to the next line worth handing out; false at the end of the text.
    fn next_line(&mut self) -> bool {
        while self.position < self.data.len() {
            let rest = &self.data[self.position..];
            let end = memchr::memchr(b'\n', rest).map_or(rest.len(), |at| at + 1);
            let raw = &rest[..end];
            self.position += end;
            self.line.clear();
            self.consumed = 0;
            // Words as tobj splits them (`str::split_whitespace`: Unicode whitespace, so a
            // vertical tab or a no-break space separates words for it as for this). A line
            // that is not UTF-8 goes to tobj as it is, which refuses it.
            let mut words = std::str::from_utf8(raw).ok().map(str::split_whitespace);
            match words.as_mut().and_then(Iterator::next) {
                Some("l") => continue,
                Some("f") if raw.contains(&b'/') => {
                    self.line.push(b'f');
                    for corner in words.into_iter().flatten() {
                        self.line.push(b' ');
                        let vertex = corner.split('/').next().unwrap_or(corner);
                        self.line.extend_from_slice(vertex.as_bytes());
                    }
                    self.line.push(b'\n');
                }
                _ => self.line.extend_from_slice(raw),
            }
            return true;
        }
        false
    }
}

impl Read for ObjReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.fill_buf()?.read(buf)?;
        self.consume(n);
        Ok(n)
    }
}

impl BufRead for ObjReader<'_> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.consumed >= self.line.len() && !self.next_line() {
            return Ok(&[]);
        }
        Ok(&self.line[self.consumed..])
    }
    fn consume(&mut self, amount: usize) {
        self.consumed = (self.consumed + amount).min(self.line.len());
    }
}

/// Reads an OBJ file's bytes into `soup`, one part per object or group, with colours from
/// the material libraries `materials` lets it read (none: no library is read).
pub fn read_obj(
    data: &[u8],
    default_name: &str,
    materials: Option<&MaterialFiles>,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let data = &*prepare(data)?;
    let mut reader = ObjReader::new(data);
    let libraries = std::cell::RefCell::new(Libraries::default());
    let loaded = tobj::load_obj_buf(&mut reader, &options, |name| match materials {
        Some(files) => files.load(name, &libraries),
        // Bytes from memory: never touch the file system.
        None => Err(tobj::LoadError::OpenFileFailed),
    });
    soup.warnings
        .extend(std::mem::take(&mut libraries.borrow_mut().warnings));
    let (models, materials) = match loaded {
        Ok((models, materials)) => (models, materials.unwrap_or_default()),
        Err(tobj::LoadError::FaceVertexOutOfBounds) => return Err(locate_bad_face_index(data)),
        Err(error) => {
            return Err(FormatError::syntax(
                Location::Line(reader.current_line()),
                error.to_string(),
            ));
        }
    };
    // tobj splits a group where its material changes: one part per run of equal names.
    let mut groups = 0usize;
    let mut previous: Option<&str> = None;
    let mut part = 0u32;
    let mut color = crate::soup::ColorSum::default();
    let distinct = models
        .iter()
        .enumerate()
        .filter(|(i, m)| *i == 0 || models[i - 1].name != m.name)
        .count();
    for model in &models {
        if previous != Some(model.name.as_str()) {
            if previous.is_some() {
                soup.parts[part as usize].color = color.mean();
            }
            color = Default::default();
            let name = if model.name.is_empty() || model.name == "unnamed_object" {
                if distinct == 1 {
                    default_name.to_string()
                } else {
                    format!("{default_name}#{groups}")
                }
            } else {
                model.name.clone()
            };
            groups += 1;
            part = soup.begin_part(name);
            previous = Some(model.name.as_str());
        }
        if let Some(rgba) = model
            .mesh
            .material_id
            .and_then(|m| materials.get(m))
            .and_then(material_color)
        {
            color.add_weighted(rgba, (model.mesh.indices.len() / 3) as u64);
        }
        let mesh = &model.mesh;
        let base = soup.positions.len();
        for p in mesh.positions.chunks_exact(3) {
            if let Err(error) = soup.push_vertex([p[0], p[1], p[2]], || Location::File) {
                return Err(locate_bad_vertex(data).unwrap_or(error));
            }
        }
        let vertex_count = soup.positions.len() - base;
        for (face, t) in mesh.indices.chunks_exact(3).enumerate() {
            let mut corners = [0u32; 3];
            for (corner, &index) in corners.iter_mut().zip(t) {
                // tobj bounds-checks indices; keep our own check as the contract.
                *corner = base as u32
                    + crate::soup::check_index(i64::from(index), vertex_count, || {
                        Location::Element {
                            kind: format!("object '{}' face", model.name),
                            index: face as u64,
                        }
                    })?;
            }
            soup.push_polygon(part, &corners);
        }
    }
    if previous.is_some() {
        soup.parts[part as usize].color = color.mean();
    }
    Ok(())
}

/// Lines of an OBJ file with their 1-based numbers and first keyword.
fn statements(data: &[u8]) -> impl Iterator<Item = (u64, &str, std::str::SplitWhitespace<'_>)> {
    data.split(|&b| b == b'\n')
        .enumerate()
        .filter_map(|(i, line)| {
            let text = std::str::from_utf8(line).ok()?;
            let mut words = text.split_whitespace();
            let keyword = words.next()?;
            Some((i as u64 + 1, keyword, words))
        })
}

/// Finds the first `v` line with a NaN, infinite or out-of-range coordinate (error path
/// only).
fn locate_bad_vertex(data: &[u8]) -> Option<FormatError> {
    statements(data)
        .filter(|(_, keyword, _)| *keyword == "v")
        .find_map(|(line, _, words)| {
            let mut p = [0f32; 3];
            for (c, word) in p.iter_mut().zip(words.take(3)) {
                *c = word.parse().unwrap_or(0.0);
            }
            let problem = crate::soup::check_position(p).err()?;
            Some(FormatError::new(Location::Line(line), problem))
        })
}

/// Finds the first face corner that refers to a vertex not yet defined (error path only).
fn locate_bad_face_index(data: &[u8]) -> FormatError {
    let mut vertex_count: i64 = 0;
    for (line, keyword, words) in statements(data) {
        match keyword {
            "v" => vertex_count += 1,
            "f" => {
                for word in words {
                    let Some(Ok(written)) = word.split('/').next().map(str::parse::<i64>) else {
                        continue;
                    };
                    let index = if written < 0 {
                        vertex_count + written
                    } else {
                        written - 1
                    };
                    if index < 0 || index >= vertex_count {
                        return FormatError::new(
                            Location::Line(line),
                            Problem::IndexOutOfRange {
                                index: written,
                                vertex_count: vertex_count as u64,
                            },
                        );
                    }
                }
            }
            _ => {}
        }
    }
    FormatError::new(
        Location::File,
        Problem::Syntax("a face refers to a vertex that does not exist".into()),
    )
}
