//! Lights files: many point lights as text, for rendering with user-made lights instead of
//! traced VPLs (`prt manylight --lights-file`).
//!
//! The format is documented on [`read_lights_file`].

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use glam::Vec3;
use thiserror::Error;

use crate::vpl::Vpl;

/// The longest line a lights file may have, in bytes (its newline excluded).
pub const MAX_LIGHTS_LINE_BYTES: usize = 4096;

/// Errors of reading or writing a lights file.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum LightsFileError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file could not be written (written to a temporary file and renamed, so a failure
    /// leaves no partial file under its name).
    #[error("cannot write {path}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: prt_texture::TextureError,
    },
    /// A line is not nine numbers (or not UTF-8).
    #[error("line {line}: {why}")]
    Syntax {
        /// Line number, from 1.
        line: usize,
        /// What is wrong.
        why: String,
    },
    /// A line is longer than [`MAX_LIGHTS_LINE_BYTES`].
    #[error("line {line} is longer than {MAX_LIGHTS_LINE_BYTES} bytes")]
    LineTooLong {
        /// Line number, from 1.
        line: usize,
    },
    /// A number is NaN or infinite.
    #[error("line {line}: light {light}: its {field} is not finite")]
    NonFinite {
        /// Line number, from 1.
        line: usize,
        /// Index of the light, from 0.
        light: usize,
        /// "position", "normal" or "power".
        field: &'static str,
    },
    /// A power is negative in a channel, or zero in all three.
    #[error("line {line}: light {light}: power {power:?} is {}", sign_of(power))]
    NonPositivePower {
        /// Line number, from 1.
        line: usize,
        /// Index of the light, from 0.
        light: usize,
        /// The power as written.
        power: [f32; 3],
    },
    /// The file holds no light.
    #[error("the file holds no light")]
    Empty,
    /// The lights would take more memory than the budget allows (counted before any is
    /// stored).
    #[error(
        "{lights} lights need about {bytes} bytes ({per_light} per light), over the memory budget of {budget} bytes"
    )]
    OverBudget {
        /// Lights in the file.
        lights: u64,
        /// Estimated bytes: `lights × per_light`.
        bytes: u64,
        /// Bytes per light of the estimate.
        per_light: u64,
        /// The budget.
        budget: u64,
    },
}

/// "negative" for a power with a negative channel, else "zero".
fn sign_of(power: &[f32; 3]) -> &'static str {
    if power.iter().any(|&p| p < 0.0) {
        "negative"
    } else {
        "zero"
    }
}

/// How much memory the lights of a file may take: the reader counts them first and refuses a
/// file whose `lights × bytes_per_light` exceeds `max_bytes`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightsBudget {
    /// The budget in bytes.
    pub max_bytes: u64,
    /// Bytes each light costs the caller: at least the [`Vpl`] itself; a renderer adds what it
    /// keeps per light (e.g. its sampled rows).
    pub bytes_per_light: u64,
}

impl LightsBudget {
    /// `max_bytes` for the [`Vpl`]s alone.
    pub fn new(max_bytes: u64) -> Self {
        Self {
            max_bytes,
            bytes_per_light: std::mem::size_of::<Vpl>() as u64,
        }
    }

    /// The same budget with `bytes` per light (never below the size of a [`Vpl`]).
    pub fn with_bytes_per_light(self, bytes: u64) -> Self {
        Self {
            bytes_per_light: bytes.max(std::mem::size_of::<Vpl>() as u64),
            ..self
        }
    }

    fn check(&self, lights: u64) -> Result<(), LightsFileError> {
        let bytes = lights.saturating_mul(self.bytes_per_light);
        if bytes > self.max_bytes {
            return Err(LightsFileError::OverBudget {
                lights,
                bytes,
                per_light: self.bytes_per_light,
                budget: self.max_bytes,
            });
        }
        Ok(())
    }
}

/// Reads the lights of a lights file within `budget`: a first pass counts them, a second parses
/// them, so neither the file nor more lights than the budget allows are ever held in memory.
///
/// The format is UTF-8 text, one light per line:
///
/// ```text
/// # x y z   nx ny nz   r g b
/// 0.0 1.98 0.0   0 -1 0   2.5 2.2 1.8
/// 0.4 0.5 -0.3   0 0 0    1.0 1.0 1.0
/// ```
///
/// nine numbers separated by whitespace: the position, the normal of the side the light
/// radiates from (normalised on reading; all zeros for an isotropic point light) and its power
/// (radiant flux, linear RGB). An oriented light radiates like a Lambertian emitter
/// (intensity `Φ cos θ / π`), an isotropic one `Φ / 4π` in every direction, as a [`Vpl`] does.
/// `#` starts a comment that runs to the end of its line; blank lines are skipped; lines are at
/// most [`MAX_LIGHTS_LINE_BYTES`] long. Every power must be non-negative in each channel and not
/// all zero. Lights read are [`Vpl`]s on an emitter (bounce 0, no albedo).
///
/// Errors: every [`LightsFileError`] but `Write`.
pub fn read_lights_file(path: &Path, budget: &LightsBudget) -> Result<Vec<Vpl>, LightsFileError> {
    let open = || {
        File::open(path)
            .map(BufReader::new)
            .map_err(|source| LightsFileError::Io {
                path: path.to_owned(),
                source,
            })
    };
    let io = |source| LightsFileError::Io {
        path: path.to_owned(),
        source,
    };
    read_lights(open()?, open()?, budget, io)
}

/// Parses lights-file text (the format of [`read_lights_file`]) within `budget`.
///
/// Errors: every [`LightsFileError`] but `Io` and `Write`.
pub fn parse_lights(text: &[u8], budget: &LightsBudget) -> Result<Vec<Vpl>, LightsFileError> {
    read_lights(text, text, budget, |source| LightsFileError::Io {
        path: PathBuf::new(),
        source,
    })
}

/// The text of a lights file holding `lights` (position, normal, flux; albedo and bounce are not
/// kept). Reading it back gives the same positions and powers bit for bit, and the same unit (or
/// zero) normals up to the rounding of their normalisation.
pub fn format_lights(lights: &[Vpl]) -> String {
    let mut out = String::from("# x y z   nx ny nz   r g b (power)\n");
    for v in lights {
        let [p, n, f] = [v.position, v.normal, v.flux];
        out.push_str(&format!(
            "{} {} {}   {} {} {}   {} {} {}\n",
            p.x, p.y, p.z, n.x, n.y, n.z, f.x, f.y, f.z
        ));
    }
    out
}

/// Writes `lights` as a lights file ([`format_lights`]), atomically.
///
/// Errors: [`LightsFileError::Write`].
pub fn write_lights_file(path: &Path, lights: &[Vpl]) -> Result<(), LightsFileError> {
    prt_texture::write_atomic(path, format_lights(lights).as_bytes()).map_err(|source| {
        LightsFileError::Write {
            path: path.to_owned(),
            source,
        }
    })
}

/// Counts the lights of `first`, checks the budget, parses `second` (the same text).
fn read_lights(
    first: impl BufRead,
    second: impl BufRead,
    budget: &LightsBudget,
    io: impl Fn(std::io::Error) -> LightsFileError,
) -> Result<Vec<Vpl>, LightsFileError> {
    let mut count = 0u64;
    for_each_line(first, &io, |_, text| {
        count += u64::from(!data_of(text).is_empty());
        Ok(())
    })?;
    budget.check(count)?;
    if count == 0 {
        return Err(LightsFileError::Empty);
    }
    // The budget bounds the count, so the allocation is bounded too.
    let mut lights = Vec::with_capacity(count as usize);
    for_each_line(second, &io, |line, text| {
        if let Some(light) = parse_line(line, lights.len(), data_of(text))? {
            lights.push(light);
        }
        Ok(())
    })?;
    Ok(lights)
}

/// The part of a line before its comment, trimmed.
fn data_of(text: &str) -> &str {
    text.split('#').next().unwrap_or_default().trim()
}

/// Calls `each(line number, text)` for every line of `reader`, reading at most
/// [`MAX_LIGHTS_LINE_BYTES`] + 1 bytes per line.
fn for_each_line(
    mut reader: impl BufRead,
    io: &impl Fn(std::io::Error) -> LightsFileError,
    mut each: impl FnMut(usize, &str) -> Result<(), LightsFileError>,
) -> Result<(), LightsFileError> {
    let mut buffer = Vec::new();
    for line in 1.. {
        buffer.clear();
        let limit = (MAX_LIGHTS_LINE_BYTES + 2) as u64;
        let read = reader
            .by_ref()
            .take(limit)
            .read_until(b'\n', &mut buffer)
            .map_err(io)?;
        if read == 0 {
            return Ok(());
        }
        let ended = buffer.last() == Some(&b'\n');
        if ended {
            buffer.pop();
        }
        if buffer.last() == Some(&b'\r') {
            buffer.pop();
        }
        if buffer.len() > MAX_LIGHTS_LINE_BYTES || (!ended && read as u64 == limit) {
            return Err(LightsFileError::LineTooLong { line });
        }
        let text = std::str::from_utf8(&buffer).map_err(|_| LightsFileError::Syntax {
            line,
            why: "not UTF-8 text".into(),
        })?;
        each(line, text)?;
    }
    Ok(())
}

/// The light of one line's data (`None` for an empty one).
fn parse_line(line: usize, light: usize, data: &str) -> Result<Option<Vpl>, LightsFileError> {
    const FIELDS: [&str; 9] = [
        "x",
        "y",
        "z",
        "normal x",
        "normal y",
        "normal z",
        "red power",
        "green power",
        "blue power",
    ];
    if data.is_empty() {
        return Ok(None);
    }
    let words: Vec<&str> = data.split_whitespace().collect();
    if words.len() != 9 {
        return Err(LightsFileError::Syntax {
            line,
            why: format!("{} numbers, expected 9 (x y z, normal, power)", words.len()),
        });
    }
    let mut v = [0.0f32; 9];
    for (k, word) in words.iter().enumerate() {
        v[k] = word.parse().map_err(|_| LightsFileError::Syntax {
            line,
            why: format!("{} {word:?} is not a number", FIELDS[k]),
        })?;
    }
    for (field, range) in [("position", 0..3), ("normal", 3..6), ("power", 6..9)] {
        if !v[range].iter().all(|x| x.is_finite()) {
            return Err(LightsFileError::NonFinite { line, light, field });
        }
    }
    let power = [v[6], v[7], v[8]];
    if power.iter().any(|&p| p < 0.0) || power.iter().all(|&p| p == 0.0) {
        return Err(LightsFileError::NonPositivePower { line, light, power });
    }
    let normal = Vec3::new(v[3], v[4], v[5]);
    // A normal too short to normalise in f32 is as good as none: the light is isotropic.
    let normal = normal.try_normalize().unwrap_or(Vec3::ZERO);
    Ok(Some(Vpl {
        position: Vec3::new(v[0], v[1], v[2]),
        normal,
        flux: Vec3::from(power),
        albedo: Vec3::ZERO,
        bounce: 0,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(text: &str) -> Result<Vec<Vpl>, LightsFileError> {
        parse_lights(text.as_bytes(), &LightsBudget::new(1 << 20))
    }

    #[test]
    fn lines_comments_and_blank_lines() {
        let lights =
            parse("# header\n\n0 1 2  0 -2 0  1 2 3 # a spot\r\n  4 5 6 0 0 0 0 0 0.5\n# end")
                .expect("valid");
        assert_eq!(lights.len(), 2);
        assert_eq!(lights[0].position, Vec3::new(0.0, 1.0, 2.0));
        assert_eq!(lights[0].normal, Vec3::NEG_Y);
        assert_eq!(lights[0].flux, Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(lights[1].normal, Vec3::ZERO);
        assert_eq!((lights[1].bounce, lights[1].albedo), (0, Vec3::ZERO));
    }

    #[test]
    fn bad_input_is_a_typed_error_naming_the_light() {
        let err = parse("0 0 0 0 1 0 1 1 1\n0 0 0 0 NaN 0 1 1 1\n").unwrap_err();
        assert!(matches!(
            err,
            LightsFileError::NonFinite {
                line: 2,
                light: 1,
                field: "normal"
            }
        ));
        assert!(matches!(
            parse("0 0 inf 0 1 0 1 1 1").unwrap_err(),
            LightsFileError::NonFinite {
                field: "position",
                ..
            }
        ));
        let zero = parse("# c\n0 0 0 0 1 0 0 0 0").unwrap_err();
        assert!(matches!(
            zero,
            LightsFileError::NonPositivePower {
                line: 2,
                light: 0,
                ..
            }
        ));
        assert!(zero.to_string().ends_with("is zero"), "{zero}");
        let negative = parse("0 0 0 0 1 0 1 -1 1").unwrap_err();
        assert!(negative.to_string().ends_with("is negative"), "{negative}");
        assert!(matches!(
            parse("0 0 0 0 1 0 1 1").unwrap_err(),
            LightsFileError::Syntax { line: 1, .. }
        ));
        assert!(matches!(
            parse("0 0 0 0 1 0 1 1 x").unwrap_err(),
            LightsFileError::Syntax { .. }
        ));
        assert!(matches!(
            parse("# nothing\n\n").unwrap_err(),
            LightsFileError::Empty
        ));
        let long = format!("0 0 0 0 1 0 1 1 1 #{}", "x".repeat(MAX_LIGHTS_LINE_BYTES));
        assert!(matches!(
            parse(&long).unwrap_err(),
            LightsFileError::LineTooLong { line: 1 }
        ));
        assert!(matches!(
            parse_lights(b"0 0 0 0 1 0 1 1 \xff", &LightsBudget::new(1 << 20)).unwrap_err(),
            LightsFileError::Syntax { .. }
        ));
    }

    #[test]
    fn the_budget_is_checked_on_the_count_before_parsing() {
        let text = "0 0 0 0 1 0 1 1 1\n".repeat(10) + "garbage";
        let per_light = std::mem::size_of::<Vpl>() as u64;
        // Ten lights and a bad line: over budget is reported first, from the count alone.
        let err = parse_lights(text.as_bytes(), &LightsBudget::new(10 * per_light)).unwrap_err();
        assert!(matches!(
            err,
            LightsFileError::OverBudget { lights: 11, .. }
        ));
        let budget = LightsBudget::new(1000).with_bytes_per_light(100);
        let fits = "0 0 0 0 1 0 1 1 1\n".repeat(10);
        assert_eq!(
            parse_lights(fits.as_bytes(), &budget).expect("fits").len(),
            10
        );
        let over = "0 0 0 0 1 0 1 1 1\n".repeat(11);
        assert!(matches!(
            parse_lights(over.as_bytes(), &budget).unwrap_err(),
            LightsFileError::OverBudget {
                lights: 11,
                bytes: 1100,
                per_light: 100,
                budget: 1000
            }
        ));
    }

    #[test]
    fn files_round_trip_and_missing_files_are_io_errors() {
        let dir = std::env::temp_dir().join(format!("prt-lights-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("lights.txt");
        let lights = parse("1 2 3 0 0 1 4 5 6\n-1 0.5 0 0 0 0 0.25 0 0").expect("valid");
        write_lights_file(&path, &lights).expect("written");
        let back = read_lights_file(&path, &LightsBudget::new(1 << 20)).expect("read");
        assert_eq!(back, lights);
        let missing = read_lights_file(&dir.join("none.txt"), &LightsBudget::new(1 << 20));
        assert!(matches!(missing, Err(LightsFileError::Io { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn finite() -> impl Strategy<Value = f32> {
        -1e30f32..1e30
    }

    proptest! {
        /// format_lights then parse_lights gives the lights back bit for bit.
        #[test]
        fn format_then_parse_is_the_identity(
            lights in prop::collection::vec(
                (
                    [finite(), finite(), finite()],
                    prop::option::of(prop::array::uniform3(-1.0f32..1.0)),
                    [0.0f32..1e6, 0.0f32..1e6, 1e-6f32..1e6],
                ),
                1..20,
            )
        ) {
            let lights: Vec<Vpl> = lights
                .into_iter()
                .map(|(p, n, f)| Vpl {
                    position: Vec3::from(p),
                    normal: n.and_then(|n| Vec3::from(n).try_normalize()).unwrap_or(Vec3::ZERO),
                    flux: Vec3::from(f),
                    albedo: Vec3::ZERO,
                    bounce: 0,
                })
                .collect();
            let back = parse_lights(format_lights(&lights).as_bytes(), &LightsBudget::new(1 << 20))
                .expect("valid");
            // Normalising an already unit normal may move it by an ulp; positions and powers
            // are exact.
            prop_assert_eq!(back.len(), lights.len());
            for (a, b) in back.iter().zip(&lights) {
                prop_assert_eq!((a.position, a.flux), (b.position, b.flux));
                prop_assert!((a.normal - b.normal).length() < 1e-6);
            }
        }

        /// Any bytes give lights or a typed error, never a panic, and never more lights than
        /// the budget allows.
        #[test]
        fn any_text_gives_lights_or_an_error(text in prop::collection::vec(any::<u8>(), 0..400)) {
            let budget = LightsBudget::new(4 * std::mem::size_of::<Vpl>() as u64);
            if let Ok(lights) = parse_lights(&text, &budget) {
                prop_assert!(!lights.is_empty() && lights.len() <= 4);
                for v in &lights {
                    prop_assert!(v.position.is_finite() && v.flux.min_element() >= 0.0);
                }
            }
        }
    }
}
