//! Stanford PLY: ASCII, binary little-endian and binary big-endian, any property layout
//! (extra vertex properties such as normals, colours and flags are skipped), polygon faces.
//!
//! Hand-written: the PLY crates on crates.io (`ply-rs`) are unmaintained and allocate from
//! header counts without checking them against the file. This reader checks every count
//! against the bytes that remain before it reserves memory, and names the element and row of
//! any bad value.

use crate::error::{FormatError, Location, Problem};
use crate::soup::{MeshSoup, check_index};

/// Headers longer than this are rejected: real headers are a few hundred bytes, and the limit
/// keeps a file without `end_header` from being scanned as one.
const MAX_HEADER_BYTES: usize = 1 << 20;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Property::Scalar { name, .. } | Property::List { name, .. } => name,
        }
    }

    /// The fewest bytes (binary) a value of this property can take.
    fn min_binary_bytes(&self) -> usize {
        match self {
            Property::Scalar { ty, .. } => ty.size(),
            Property::List { count, .. } => count.size(),
        }
    }
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    header_line: u64,
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    body_start: usize,
}

fn parse_header(data: &[u8]) -> Result<Header, FormatError> {
    let limit = data.len().min(MAX_HEADER_BYTES);
    let mut lines = data[..limit].split_inclusive(|&b| b == b'\n');
    let mut offset = 0usize;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_number = 0u64;
    let mut next_line = |offset: &mut usize, line_number: &mut u64| {
        let raw = lines.next()?;
        *offset += raw.len();
        *line_number += 1;
        Some(String::from_utf8_lossy(raw).trim().to_string())
    };
    match next_line(&mut offset, &mut line_number) {
        Some(magic) if magic == "ply" => {}
        _ => {
            return Err(FormatError::syntax(
                Location::Line(1),
                "missing 'ply' magic line",
            ));
        }
    }
    loop {
        let Some(line) = next_line(&mut offset, &mut line_number) else {
            return Err(FormatError::syntax(
                Location::Line(line_number),
                "header has no 'end_header' line",
            ));
        };
        let at = Location::Line(line_number);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["end_header"] => break,
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, _version] => {
                encoding = Some(match *kind {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLittleEndian,
                    "binary_big_endian" => Encoding::BinaryBigEndian,
                    other => {
                        return Err(FormatError::syntax(at, format!("unknown format '{other}'")));
                    }
                });
            }
            ["element", name, count] => {
                let count = count.parse::<u64>().map_err(|_| {
                    FormatError::syntax(at.clone(), format!("bad element count '{count}'"))
                })?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                    header_line: line_number,
                });
            }
            ["property", "list", count, item, name] => {
                let (Some(count), Some(item)) = (Scalar::parse(count), Scalar::parse(item)) else {
                    return Err(FormatError::syntax(at, format!("unknown type in '{line}'")));
                };
                if !count.is_integer() {
                    return Err(FormatError::syntax(
                        at,
                        "list count type must be an integer",
                    ));
                }
                let element = elements
                    .last_mut()
                    .ok_or_else(|| FormatError::syntax(at, "property before any element"))?;
                element.properties.push(Property::List {
                    name: name.to_string(),
                    count,
                    item,
                });
            }
            ["property", ty, name] => {
                let ty = Scalar::parse(ty).ok_or_else(|| {
                    FormatError::syntax(at.clone(), format!("unknown type '{ty}'"))
                })?;
                let element = elements
                    .last_mut()
                    .ok_or_else(|| FormatError::syntax(at, "property before any element"))?;
                element.properties.push(Property::Scalar {
                    name: name.to_string(),
                    ty,
                });
            }
            _ => {
                return Err(FormatError::syntax(
                    at,
                    format!("unexpected header line '{line}'"),
                ));
            }
        }
    }
    let encoding = encoding
        .ok_or_else(|| FormatError::syntax(Location::Line(1), "header has no 'format' line"))?;
    Ok(Header {
        encoding,
        elements,
        body_start: offset,
    })
}

/// Reads values of the body one at a time, in either encoding.
trait Values {
    /// Reads a value of type `ty` as a float.
    fn real(&mut self, ty: Scalar) -> Result<f64, FormatError>;
    /// Reads a value of integer type `ty`.
    fn integer(&mut self, ty: Scalar) -> Result<i64, FormatError>;
    /// Bytes not yet read.
    fn remaining(&self) -> usize;
    /// Where the next value starts.
    fn location(&self) -> Location;
}

struct Binary<'a> {
    data: &'a [u8],
    position: usize,
    big_endian: bool,
}

impl Binary<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], FormatError> {
        let bytes = self
            .data
            .get(self.position..self.position + N)
            .ok_or_else(|| {
                FormatError::new(
                    Location::Byte(self.position as u64),
                    Problem::Truncated {
                        needed: N as u64,
                        available: (self.data.len() - self.position) as u64,
                    },
                )
            })?;
        self.position += N;
        let mut out: [u8; N] = bytes.try_into().expect("slice of N bytes");
        if self.big_endian {
            out.reverse();
        }
        Ok(out)
    }
}

impl Values for Binary<'_> {
    fn real(&mut self, ty: Scalar) -> Result<f64, FormatError> {
        Ok(match ty {
            Scalar::F32 => f64::from(f32::from_le_bytes(self.take()?)),
            Scalar::F64 => f64::from_le_bytes(self.take()?),
            _ => self.integer(ty)? as f64,
        })
    }

    fn integer(&mut self, ty: Scalar) -> Result<i64, FormatError> {
        Ok(match ty {
            Scalar::I8 => i64::from(i8::from_le_bytes(self.take()?)),
            Scalar::U8 => i64::from(u8::from_le_bytes(self.take()?)),
            Scalar::I16 => i64::from(i16::from_le_bytes(self.take()?)),
            Scalar::U16 => i64::from(u16::from_le_bytes(self.take()?)),
            Scalar::I32 => i64::from(i32::from_le_bytes(self.take()?)),
            Scalar::U32 => i64::from(u32::from_le_bytes(self.take()?)),
            Scalar::F32 | Scalar::F64 => {
                return Err(FormatError::syntax(
                    self.location(),
                    "expected an integer type",
                ));
            }
        })
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.position
    }

    fn location(&self) -> Location {
        Location::Byte(self.position as u64)
    }
}

struct Ascii<'a> {
    data: &'a [u8],
    position: usize,
    line: u64,
}

impl<'a> Ascii<'a> {
    fn token(&mut self) -> Result<&'a str, FormatError> {
        while let Some(&b) = self.data.get(self.position) {
            if !b.is_ascii_whitespace() {
                break;
            }
            if b == b'\n' {
                self.line += 1;
            }
            self.position += 1;
        }
        let start = self.position;
        while self
            .data
            .get(self.position)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.position += 1;
        }
        if start == self.position {
            return Err(FormatError::new(
                Location::Line(self.line),
                Problem::Truncated {
                    needed: 1,
                    available: 0,
                },
            ));
        }
        std::str::from_utf8(&self.data[start..self.position])
            .map_err(|_| FormatError::syntax(Location::Line(self.line), "value is not ASCII"))
    }
}

impl Values for Ascii<'_> {
    fn real(&mut self, _ty: Scalar) -> Result<f64, FormatError> {
        let token = self.token()?;
        token.parse().map_err(|_| {
            FormatError::syntax(Location::Line(self.line), format!("bad number '{token}'"))
        })
    }

    fn integer(&mut self, _ty: Scalar) -> Result<i64, FormatError> {
        let token = self.token()?;
        token.parse().map_err(|_| {
            FormatError::syntax(Location::Line(self.line), format!("bad integer '{token}'"))
        })
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.position
    }

    fn location(&self) -> Location {
        Location::Line(self.line)
    }
}

/// Reads a PLY file's bytes into `soup` as one part named `name`.
pub fn read_ply(data: &[u8], name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    let header = parse_header(data)?;
    let body = &data[header.body_start..];
    match header.encoding {
        Encoding::Ascii => {
            let header_lines = data[..header.body_start]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
            let mut values = Ascii {
                data: body,
                position: 0,
                line: header_lines as u64 + 1,
            };
            read_body(&header, &mut values, true, name, soup)
        }
        encoding => {
            let mut values = Binary {
                data: body,
                position: 0,
                big_endian: encoding == Encoding::BinaryBigEndian,
            };
            read_body(&header, &mut values, false, name, soup)
        }
    }
}

/// Reads every element in header order. For `ascii` bodies a value takes at least two bytes
/// (a digit and a separator), which bounds how many rows the remaining bytes can hold.
fn read_body(
    header: &Header,
    values: &mut impl Values,
    ascii: bool,
    name: &str,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let vertex_count = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map_or(0, |e| e.count);
    let base = soup.positions.len();
    let part = soup.begin_part(name);
    let mut saw_faces = false;
    for element in &header.elements {
        let min_row_bytes: usize = element
            .properties
            .iter()
            .map(|p| if ascii { 2 } else { p.min_binary_bytes() })
            .sum();
        if min_row_bytes == 0 {
            continue; // An element without properties occupies no bytes.
        }
        let max_possible = (values.remaining() / min_row_bytes) as u64;
        if element.count > max_possible {
            return Err(FormatError::new(
                Location::Line(element.header_line),
                Problem::CountExceedsFile {
                    what: format!("element '{}'", element.name),
                    count: element.count,
                    max_possible,
                },
            ));
        }
        match element.name.as_str() {
            "vertex" => read_vertices(element, values, soup)?,
            "face" => {
                saw_faces = true;
                read_faces(element, values, vertex_count, base, part, soup)?;
            }
            _ => skip_rows(element, values)?,
        }
    }
    if !saw_faces && header.elements.iter().any(|e| e.name == "tristrips") {
        return Err(FormatError::new(
            Location::File,
            Problem::Unsupported("PLY 'tristrips' element without 'face'".into()),
        ));
    }
    Ok(())
}

fn read_vertices(
    element: &Element,
    values: &mut impl Values,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let axis = |axis: &str| {
        element
            .properties
            .iter()
            .position(|p| matches!(p, Property::Scalar { name, .. } if name == axis))
            .ok_or_else(|| {
                FormatError::syntax(
                    Location::Line(element.header_line),
                    format!("vertex element has no scalar property '{axis}'"),
                )
            })
    };
    let slots = [axis("x")?, axis("y")?, axis("z")?];
    soup.positions.reserve(element.count as usize);
    for row in 0..element.count {
        let mut p = [0f32; 3];
        for (index, property) in element.properties.iter().enumerate() {
            match property {
                Property::Scalar { ty, .. } => {
                    let value = values.real(*ty)?;
                    if let Some(axis) = slots.iter().position(|&s| s == index) {
                        p[axis] = value as f32;
                    }
                }
                Property::List { count, item, .. } => skip_list(values, *count, *item)?,
            }
        }
        soup.push_vertex(p, || Location::Element {
            kind: "vertex".into(),
            index: row,
        })?;
    }
    Ok(())
}

fn read_faces(
    element: &Element,
    values: &mut impl Values,
    vertex_count: u64,
    base: usize,
    part: u32,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let corners_slot = element
        .properties
        .iter()
        .position(|p| {
            matches!(p, Property::List { .. })
                && (p.name() == "vertex_indices" || p.name() == "vertex_index")
        })
        .ok_or_else(|| {
            FormatError::syntax(
                Location::Line(element.header_line),
                "face element has no list property 'vertex_indices'",
            )
        })?;
    soup.triangles.reserve(element.count as usize);
    soup.triangle_parts.reserve(element.count as usize);
    let mut corners: Vec<u32> = Vec::new();
    for row in 0..element.count {
        for (index, property) in element.properties.iter().enumerate() {
            match property {
                Property::List { count, item, .. } if index == corners_slot => {
                    let at = values.location();
                    let n = values.integer(*count)?;
                    if n < 0 || n as usize > values.remaining() {
                        return Err(FormatError::new(
                            at,
                            Problem::CountExceedsFile {
                                what: format!("corner list of face {row}"),
                                count: n as u64,
                                max_possible: values.remaining() as u64,
                            },
                        ));
                    }
                    corners.clear();
                    for _ in 0..n {
                        let index = values.integer(*item).map_err(|e| match e.problem {
                            Problem::Syntax(_) => FormatError::syntax(
                                e.location,
                                "face vertex indices must have an integer type",
                            ),
                            _ => e,
                        })?;
                        let vertex =
                            check_index(index, vertex_count as usize, || Location::Element {
                                kind: "face".into(),
                                index: row,
                            })?;
                        corners.push(base as u32 + vertex);
                    }
                    soup.push_polygon(part, &corners);
                }
                Property::List { count, item, .. } => skip_list(values, *count, *item)?,
                Property::Scalar { ty, .. } => {
                    values.real(*ty)?;
                }
            }
        }
    }
    Ok(())
}

fn skip_list(values: &mut impl Values, count: Scalar, item: Scalar) -> Result<(), FormatError> {
    let at = values.location();
    let n = values.integer(count)?;
    if n < 0 || n as usize > values.remaining() {
        return Err(FormatError::new(
            at,
            Problem::CountExceedsFile {
                what: "list".into(),
                count: n as u64,
                max_possible: values.remaining() as u64,
            },
        ));
    }
    for _ in 0..n {
        values.real(item)?;
    }
    Ok(())
}

fn skip_rows(element: &Element, values: &mut impl Values) -> Result<(), FormatError> {
    for _ in 0..element.count {
        for property in &element.properties {
            match property {
                Property::Scalar { ty, .. } => {
                    values.real(*ty)?;
                }
                Property::List { count, item, .. } => skip_list(values, *count, *item)?,
            }
        }
    }
    Ok(())
}
