//! The streaming parser against `tobj` (`reference.rs`) on the same bytes: real files,
//! generated ones, and the same text read whole, streamed in small chunks, with every line
//! ending.

use super::*;

fn parsed(text: &[u8]) -> Result<MeshSoup, FormatError> {
    let mut soup = MeshSoup::default();
    read_obj(text, "model", None, &mut soup).map(|()| soup)
}

fn by_reference(text: &[u8]) -> Result<MeshSoup, FormatError> {
    let mut soup = MeshSoup::default();
    reference::read_obj(text, "model", None, &mut soup).map(|()| soup)
}

/// A source that hands out at most `step` bytes per read, to cut lines and line breaks at
/// every place.
struct Trickle<'a> {
    text: &'a [u8],
    step: usize,
}

impl Read for Trickle<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.step.min(buf.len()).min(self.text.len());
        buf[..n].copy_from_slice(&self.text[..n]);
        self.text = &self.text[n..];
        Ok(n)
    }
}

fn streamed(text: &[u8], step: usize) -> Result<MeshSoup, FormatError> {
    let mut soup = MeshSoup::default();
    let mut source = Trickle { text, step };
    match read_obj_stream(&mut source, "model", None, &mut soup) {
        Ok(()) => Ok(soup),
        Err(StreamError::Format(e)) => Err(e),
        Err(StreamError::Read(e)) => panic!("{e}"),
    }
}

fn shared(name: &str) -> Vec<u8> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    std::fs::read(path.join(name)).unwrap()
}

#[test]
fn shared_meshes_read_as_tobj_reads_them() {
    for name in ["bunny.obj", "as1_assembly.obj", "airplane.obj", "cow.obj"] {
        let text = shared(name);
        let ours = parsed(&text).unwrap();
        assert_eq!(ours, by_reference(&text).unwrap(), "{name}");
        assert!(!ours.triangles.is_empty());
    }
}

#[test]
fn streaming_in_small_chunks_reads_the_same() {
    let text = shared("as1_assembly.obj");
    let whole = parsed(&text).unwrap();
    for step in [1, 7, 4096] {
        assert_eq!(streamed(&text, step).unwrap(), whole, "step {step}");
    }
}

const SAMPLE: &str = "# a comment\nmtllib parts.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0 2\nvt 0 0\nvn 0 0 1\nf 1 2 3\no plate\nusemtl steel\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -1 -2 -3\ng\nf 2 3 4\np 1\nl 1 2 3\ng plate\nf 1 2 4\ns off\n";

#[test]
fn every_line_ending_reads_the_same() {
    let lf = parsed(SAMPLE.as_bytes()).unwrap();
    assert_eq!(lf, by_reference(SAMPLE.as_bytes()).unwrap());
    assert_eq!(lf.part_names, ["model#0", "plate", "model#2", "plate"]);
    assert!(lf.positions.contains(&[0.5, 0.5, 0.0]));
    for ending in ["\r\n", "\r"] {
        let text = SAMPLE.replace('\n', ending);
        for step in [1, 2, 3, 5, 1 << 20] {
            assert_eq!(
                streamed(text.as_bytes(), step).unwrap(),
                lf,
                "{ending:?} {step}"
            );
        }
        assert_eq!(parsed(text.as_bytes()).unwrap(), lf, "{ending:?}");
    }
    let bom = [BYTE_ORDER_MARK, SAMPLE.as_bytes()].concat();
    assert_eq!(streamed(&bom, 1).unwrap(), lf);
}

#[test]
fn short_faces_are_counted_and_vertex_colours_skipped() {
    // `tobj` refuses colours on some vertices only; positions are all the tree needs.
    let text = b"v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 3\nf 1 2 3\n";
    let soup = parsed(text).unwrap();
    assert_eq!(soup.short_faces_dropped, 2);
    assert_eq!(soup.triangles, [[0, 1, 2]]);
    assert_eq!(soup.part_names, ["model"]);
}

#[test]
fn errors_name_their_line_in_every_reading() {
    let cases: [(&[u8], u64); 7] = [
        (b"v 0 0 0\nv 1 x 0\n", 2),
        (b"v 0 0 0\nv 1 0 0 0\n", 2),
        (b"v 0 0 0\nv 1 0 0 1 2\n", 2),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", 4),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n", 4),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl\n", 4),
    ];
    for (text, line) in cases {
        let error = parsed(text).unwrap_err();
        assert_eq!(error.location, Location::Line(line), "{error:?}");
        assert_eq!(streamed(text, 3).unwrap_err().location, error.location);
    }
    // A bad position is an error where a face uses it, named by its `v` line.
    let text = b"v 0 0 0\nv 1 0 0\nv 0 inf 0\nv 0 1 0\nf 1 2 4\nf 1 2 3\n";
    let error = parsed(text).unwrap_err();
    assert_eq!(error.location, Location::Line(3));
    assert_eq!(error.problem, Problem::NonFiniteCoordinate);
}

#[test]
fn a_line_over_the_limit_is_refused_when_streamed() {
    let mut text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n#".to_vec();
    text.resize(text.len() + MAX_LINE_BYTES + 10, b'x');
    text.extend_from_slice(b"\nf 1 2 3\n");
    let error = streamed(&text, 1 << 16).unwrap_err();
    assert_eq!(error.location, Location::Line(4));
    assert!(matches!(error.problem, Problem::LineTooLong { .. }));
    assert_eq!(parsed(&text).unwrap_err().location, Location::Line(4));
}

#[test]
fn fast_numbers_are_the_standard_parser_s() {
    let words = [
        "0",
        "-0",
        "+1",
        "1.",
        ".5",
        "-.5",
        "1e3",
        "1E-3",
        "2.5e+2",
        "0.1",
        "-0.0378297",
        "3.4028235e38",
        "3.5e38",
        "1e-38",
        "1e-45",
        "1e-50",
        "123456789012345",
        "1234567890123456",
        "16777217",
        "0.30000001192092896",
        "1.00000005960464477539",
        "e5",
        "1e",
        "--1",
        "1.2.3",
        "inf",
        "-inf",
        "nan",
        "NaN",
        "1_0",
        "0x10",
        "",
        "-",
        ".",
        "1e400",
        "1e-400",
        "9007199254740993",
        "0.000000000000000000000000000001",
    ];
    for word in words {
        let standard = word.parse::<f32>().ok();
        let ours = parse_f32(word.as_bytes());
        assert_eq!(
            ours.map(f32::to_bits),
            standard.map(f32::to_bits),
            "{word}: {ours:?} against {standard:?}"
        );
    }
}

mod generated {
    use super::*;
    use proptest::prelude::*;

    /// One statement of a small OBJ file, chosen so that it is valid for `tobj` too
    /// (corners only refer to vertices already read).
    fn statement() -> impl Strategy<Value = String> {
        prop_oneof![
            4 => (-100i32..100, -100i32..100, -100i32..100)
                .prop_map(|(x, y, z)| format!("v {} {} {}.5", x, f64::from(y) / 8.0, z)),
            4 => (prop::collection::vec(1usize..6, 3..7), any::<bool>())
                .prop_map(|(corners, relative)| {
                    let corners: Vec<String> = corners
                        .iter()
                        .map(|c| if relative { format!("-{c}") } else { format!("{c}/{c}") })
                        .collect();
                    format!("f {}", corners.join(" "))
                }),
            1 => prop::sample::select(vec!["o a", "g b", "g", "o", "g a b", "usemtl m", "s 1", "# f 9 9 9", ""])
                .prop_map(str::to_string),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]
        #[test]
        fn decimals_parse_as_the_standard_parser_parses_them(
            negative in any::<bool>(),
            whole in 0u64..100_000_000,
            fraction in prop::option::of((0u64..10_000_000_000, 0usize..12)),
            exponent in prop::option::of(-45i32..40),
        ) {
            let mut word = format!("{}{whole}", if negative { "-" } else { "" });
            if let Some((digits, zeros)) = fraction {
                word.push_str(&format!(".{}{digits}", "0".repeat(zeros)));
            }
            if let Some(e) = exponent {
                word.push_str(&format!("e{e}"));
            }
            let standard = word.parse::<f32>().unwrap();
            prop_assert_eq!(parse_f32(word.as_bytes()).map(f32::to_bits), Some(standard.to_bits()), "{}", word);
        }

        #[test]
        fn every_f32_written_shortest_reads_back(bits in any::<u32>()) {
            let value = f32::from_bits(bits);
            let word = format!("{value}");
            let standard = word.parse::<f32>().unwrap();
            prop_assert_eq!(parse_f32(word.as_bytes()).map(f32::to_bits), Some(standard.to_bits()), "{}", word);
            let word = format!("{value:e}");
            prop_assert_eq!(parse_f32(word.as_bytes()).map(f32::to_bits), Some(standard.to_bits()), "{}", word);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]
        #[test]
        fn random_files_read_as_tobj_reads_them(
            statements in prop::collection::vec(statement(), 0..60),
            step in 1usize..40,
        ) {
            let mut text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 0 1\n".to_string();
            for s in &statements {
                text.push_str(s);
                text.push('\n');
            }
            // `tobj` ends its last group with a part even when it has no face, which this
            // reader does not: the files end with a face.
            text.push_str("f 1 2 3\n");
            let ours = parsed(text.as_bytes());
            let theirs = by_reference(text.as_bytes());
            match (&ours, &theirs) {
                (Ok(a), Ok(b)) => prop_assert_eq!(a, b),
                (Err(a), Err(b)) => prop_assert_eq!(a.location.clone(), b.location.clone()),
                _ => prop_assert!(false, "{:?} against {:?}", ours, theirs),
            }
            prop_assert_eq!(streamed(text.as_bytes(), step), ours);
        }
    }
}
