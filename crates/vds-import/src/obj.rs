//! Wavefront OBJ through `tobj`: every object or group becomes a named part; polygons are
//! triangulated by `tobj`; points and lines are ignored.
//!
//! `tobj` reports what went wrong but not where, so the reader feeds it through a
//! line-counting buffer and, on the rare error path, rescans the text to name the exact line
//! of a non-finite coordinate or an out-of-range face index.

use std::io::{BufRead, Read};

use crate::error::{FormatError, Location, Problem};
use crate::soup::MeshSoup;

/// A `BufRead` over a byte slice that knows how far the consumer got, so a parse error can
/// be given a line number.
struct CountingReader<'a> {
    data: &'a [u8],
    position: usize,
}

impl CountingReader<'_> {
    /// The 1-based number of the line that was read last.
    fn current_line(&self) -> u64 {
        let consumed = &self.data[..self.position];
        let newlines = consumed.iter().filter(|&&b| b == b'\n').count() as u64;
        // A consumed line ends with its newline, so the line being parsed is the last
        // newline-terminated one; a final line without a newline adds one.
        let partial = u64::from(consumed.last().is_some_and(|&b| b != b'\n'));
        (newlines + partial).max(1)
    }
}

impl Read for CountingReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = (&self.data[self.position..]).read(buf)?;
        self.position += n;
        Ok(n)
    }
}

impl BufRead for CountingReader<'_> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        Ok(&self.data[self.position..])
    }
    fn consume(&mut self, amount: usize) {
        self.position = (self.position + amount).min(self.data.len());
    }
}

/// Reads an OBJ file's bytes into `soup`, one part per object or group.
pub fn read_obj(data: &[u8], default_name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let mut reader = CountingReader { data, position: 0 };
    let loaded = tobj::load_obj_buf(&mut reader, &options, |_| {
        // Materials carry nothing the vertex tree needs; never touch the file system.
        Err(tobj::LoadError::OpenFileFailed)
    });
    let models = match loaded {
        Ok((models, _materials)) => models,
        Err(tobj::LoadError::FaceVertexOutOfBounds) => return Err(locate_bad_face_index(data)),
        Err(error) => {
            return Err(FormatError::syntax(
                Location::Line(reader.current_line()),
                error.to_string(),
            ));
        }
    };
    for (model_index, model) in models.iter().enumerate() {
        let name = if model.name.is_empty() || model.name == "unnamed_object" {
            if models.len() == 1 {
                default_name.to_string()
            } else {
                format!("{default_name}#{model_index}")
            }
        } else {
            model.name.clone()
        };
        let part = soup.begin_part(name);
        let mesh = &model.mesh;
        let base = soup.positions.len();
        for p in mesh.positions.chunks_exact(3) {
            if let Err(error) = soup.push_vertex([p[0], p[1], p[2]], || Location::File) {
                return Err(locate_non_finite_vertex(data).unwrap_or(error));
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

/// Finds the first `v` line with a NaN or infinite coordinate (error path only).
fn locate_non_finite_vertex(data: &[u8]) -> Option<FormatError> {
    statements(data)
        .filter(|(_, keyword, _)| *keyword == "v")
        .find(|(_, _, words)| {
            words
                .clone()
                .take(3)
                .any(|w| w.parse::<f32>().is_ok_and(|c| !c.is_finite()))
        })
        .map(|(line, _, _)| FormatError::new(Location::Line(line), Problem::NonFiniteCoordinate))
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
