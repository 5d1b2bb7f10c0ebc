//! The streamed merge's files when it runs as distributed work: a tile's partial result of a
//! stage (`PLAN_DIR/merge/STAGE/tile-INDEX.part`, written by `prt merge --map`) and the basis a
//! stage's reduce fitted (`PLAN_DIR/merge/STAGE.basis`, written by `prt merge --reduce`). Both
//! are a small JSON header and a little-endian payload whose size follows from the plan, so a
//! reader checks every size before it allocates; each carries the fingerprint of what it was
//! computed from (the plan, the stage, the tile, the basis it started from), so that a partial
//! of another plan or an older basis is refused, never summed. The layout is in
//! docs/formats.md.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use prt_texture::Limits;

use super::Fnv1a64;

/// The first bytes of both files.
pub const MERGE_MAGIC: &[u8; 8] = b"PRTMERGE";
/// `format` of a partial's header.
pub const PARTIAL_FORMAT: &str = "prt merge partial";
/// `format` of a basis file's header.
pub const BASIS_FORMAT: &str = "prt merge basis";
/// The version of both (2: the loss weighting's sums and normalisation).
pub const MERGE_FILE_VERSION: u32 = 2;
/// The largest header read (the basis's carries one number per sweep).
const HEADER_MAX: u64 = 1 << 20;

/// A stage of the streamed merge: the coarse volume, an alternating sweep (1-based), or the
/// coefficients. Written `coarse`, `sweep-K`, `coefficients`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum MergeStage {
    /// Each tile's sums of the volume halved; the reduce fits MBD on it: the first basis.
    Coarse,
    /// Sweep K: each tile's part of the basis step's normal equations on basis K − 1; the
    /// reduce solves them: basis K.
    Sweep(usize),
    /// Each tile's coefficients on the last basis; the reduce writes the bake folder.
    Coefficients,
}

impl MergeStage {
    /// The stages of a merge with `sweeps` sweeps, in order.
    pub fn all(sweeps: usize) -> Vec<MergeStage> {
        std::iter::once(MergeStage::Coarse)
            .chain((1..=sweeps).map(MergeStage::Sweep))
            .chain([MergeStage::Coefficients])
            .collect()
    }

    /// The stage whose basis this stage's maps start from (`None` for the coarse stage).
    pub fn input(self, sweeps: usize) -> Option<MergeStage> {
        match self {
            MergeStage::Coarse => None,
            MergeStage::Sweep(1) => Some(MergeStage::Coarse),
            MergeStage::Sweep(k) => Some(MergeStage::Sweep(k - 1)),
            MergeStage::Coefficients if sweeps == 0 => Some(MergeStage::Coarse),
            MergeStage::Coefficients => Some(MergeStage::Sweep(sweeps)),
        }
    }

    /// Refuses a sweep outside `1..=sweeps`.
    ///
    /// # Errors
    /// [`PartialError::NoSuchStage`].
    pub fn check(self, sweeps: usize) -> Result<(), PartialError> {
        match self {
            MergeStage::Sweep(k) if k == 0 || k > sweeps => Err(PartialError::NoSuchStage {
                stage: self.to_string(),
                sweeps,
            }),
            _ => Ok(()),
        }
    }
}

impl fmt::Display for MergeStage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MergeStage::Coarse => write!(f, "coarse"),
            MergeStage::Sweep(k) => write!(f, "sweep-{k}"),
            MergeStage::Coefficients => write!(f, "coefficients"),
        }
    }
}

impl FromStr for MergeStage {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "coarse" => Ok(MergeStage::Coarse),
            "coefficients" => Ok(MergeStage::Coefficients),
            _ => s
                .strip_prefix("sweep-")
                .and_then(|k| k.parse().ok())
                .filter(|&k| k > 0)
                .map(MergeStage::Sweep)
                .ok_or_else(|| {
                    format!("{s:?} is not a stage: coarse, sweep-1, sweep-2, ..., coefficients")
                }),
        }
    }
}

/// Errors of the distributed merge's files.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum PartialError {
    /// A stage the merge does not have.
    #[error("stage {stage} does not exist in a merge of {sweeps} sweeps")]
    NoSuchStage {
        /// The stage asked for.
        stage: String,
        /// The merge's sweeps.
        sweeps: usize,
    },
    /// A file the step needs is not there.
    #[error(
        "{} is missing: run `prt merge PLAN_DIR --map --stage {stage}{}` first",
        path.display(),
        tile.map(|t| format!(" --tile {t}")).unwrap_or_else(|| " (every tile), then --reduce".into())
    )]
    Missing {
        /// The stage whose file it is.
        stage: String,
        /// The tile of a partial; `None` for a basis.
        tile: Option<usize>,
        /// The file.
        path: PathBuf,
    },
    /// A file was computed from something else than what this step has: another plan, another
    /// basis (an older run of the stage before), another tile or stage.
    #[error(
        "{} is stale: it was computed from {found}, this step expects {expected}; map the \
         stage again",
        path.display()
    )]
    Stale {
        /// The file.
        path: PathBuf,
        /// The fingerprint it records.
        found: String,
        /// The one expected.
        expected: String,
    },
    /// A file is not what it should be: bad magic, header, size, checksum or a non-finite
    /// value.
    #[error("{}: {why}", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// A size the file needs is over the reader's [`Limits`]; nothing was allocated for it.
    #[error("{}: {what} is {value} bytes, over the limit of {limit}", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// What is too large.
        what: &'static str,
        /// Its size.
        value: u64,
        /// The limit.
        limit: u64,
    },
    /// Reading or writing failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Writing failed.
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: prt_texture::TextureError,
    },
}

/// The folder of the distributed merge's files in a plan folder.
pub fn merge_dir(plan_dir: &Path) -> PathBuf {
    plan_dir.join("merge")
}

/// The partial of tile `tile` in stage `stage`.
pub fn partial_path(plan_dir: &Path, stage: MergeStage, tile: usize) -> PathBuf {
    merge_dir(plan_dir)
        .join(stage.to_string())
        .join(format!("tile-{tile}.part"))
}

/// The basis fitted by stage `stage`'s reduce.
pub fn basis_path(plan_dir: &Path, stage: MergeStage) -> PathBuf {
    merge_dir(plan_dir).join(format!("{stage}.basis"))
}

/// A partial's header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PartialHeader {
    pub format: String,
    pub version: u32,
    pub stage: String,
    pub tile: usize,
    /// [`partial_fingerprint`] of what it was computed from.
    pub fingerprint: String,
    /// `Σ‖f − f̂‖²` and `Σ‖f‖²` over the tile's valid core voxels (0 for the coarse stage).
    pub residual: f64,
    pub energy: f64,
    /// The same of the loss-weighted vectors.
    pub weighted_residual: f64,
    pub weighted_energy: f64,
    /// `Σ‖f‖` over them (the coarse stage's; 0 for the others).
    pub magnitude: f64,
    pub payload_bytes: u64,
    pub checksum: String,
}

/// A basis file's header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct BasisHeader {
    pub format: String,
    pub version: u32,
    pub stage: String,
    /// The plan's hash.
    pub plan: String,
    pub nodes: [usize; 3],
    pub rank: usize,
    pub dim: usize,
    pub coarse_grid: [usize; 3],
    pub coarse_iterations: usize,
    /// The relative error at the valid voxel centres of each basis before this one.
    pub relative_errors: Vec<f64>,
    /// The same of the loss-weighted vectors.
    pub weighted_errors: Vec<f64>,
    /// The valid voxels' mean magnitude: the loss weights' normalisation.
    pub mean_magnitude: f64,
    /// Each sweep's conjugate-gradient iterations and relative residual.
    pub basis_solves: Vec<(usize, f64)>,
    pub payload_bytes: u64,
    pub checksum: String,
}

/// The fingerprint of tile `tile`'s partial of `stage` for the plan hashed `plan` from the
/// basis fingerprinted `basis` (`""` for the coarse stage).
pub(crate) fn partial_fingerprint(
    plan: &str,
    stage: MergeStage,
    tile: usize,
    basis: &str,
) -> String {
    let mut hash = Fnv1a64::default();
    for part in [
        PARTIAL_FORMAT,
        plan,
        &stage.to_string(),
        &tile.to_string(),
        basis,
    ] {
        hash.update(part.as_bytes());
        hash.update(&[0]);
    }
    hash.label()
}

/// The fingerprint of a basis: its plan, stage and payload.
pub(crate) fn basis_fingerprint(plan: &str, stage: MergeStage, checksum: &str) -> String {
    let mut hash = Fnv1a64::default();
    for part in [BASIS_FORMAT, plan, &stage.to_string(), checksum] {
        hash.update(part.as_bytes());
        hash.update(&[0]);
    }
    hash.label()
}

/// `MAGIC, u32 header length, header JSON, payload`.
pub(crate) fn frame(header: &impl Serialize, payload: &[u8]) -> Vec<u8> {
    let header = serde_json::to_vec(header).unwrap_or_default();
    let mut out = Vec::with_capacity(12 + header.len() + payload.len());
    out.extend_from_slice(MERGE_MAGIC);
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(payload);
    out
}

/// Splits framed bytes into a header of `format` and its payload, checking the magic, the
/// version, the payload's announced size against `expected_payload` and `limits`, its actual
/// size and its checksum.
pub(crate) fn unframe<'a, H: serde::de::DeserializeOwned>(
    path: &Path,
    bytes: &'a [u8],
    format: &str,
    header_of: impl Fn(&H) -> (&str, u32, u64, &str),
    expected_payload: u64,
    limits: &Limits,
) -> Result<(H, &'a [u8]), PartialError> {
    let malformed = |why: String| PartialError::Malformed {
        path: path.to_path_buf(),
        why,
    };
    if bytes.len() < 12 || &bytes[..8] != MERGE_MAGIC {
        return Err(malformed("not a prt merge file (bad magic)".into()));
    }
    let header_len = u64::from(u32::from_le_bytes([
        bytes[8], bytes[9], bytes[10], bytes[11],
    ]));
    if header_len > HEADER_MAX || header_len > (bytes.len() - 12) as u64 {
        return Err(malformed(format!(
            "header of {header_len} bytes in a file of {}",
            bytes.len()
        )));
    }
    let (header, payload) = bytes[12..].split_at(header_len as usize);
    let header: H = serde_json::from_slice(header).map_err(|e| malformed(e.to_string()))?;
    let (found_format, version, payload_bytes, checksum) = header_of(&header);
    if found_format != format || version != MERGE_FILE_VERSION {
        return Err(malformed(format!(
            "format {found_format:?} version {version}, expected {format:?} version \
             {MERGE_FILE_VERSION}"
        )));
    }
    if expected_payload > limits.max_bytes {
        return Err(PartialError::TooLarge {
            path: path.to_path_buf(),
            what: "the payload",
            value: expected_payload,
            limit: limits.max_bytes,
        });
    }
    if payload_bytes != expected_payload || payload.len() as u64 != expected_payload {
        return Err(malformed(format!(
            "payload of {} bytes (header: {payload_bytes}), expected {expected_payload}",
            payload.len()
        )));
    }
    let found = Fnv1a64::of(payload);
    if found != checksum {
        return Err(malformed(format!(
            "payload checksum {found}, the header records {checksum}"
        )));
    }
    Ok((header, payload))
}

/// Reads a merge file whose payload must be `expected_payload` bytes: refused over `limits` or
/// over that size (plus the header cap) before it is read.
pub(crate) fn read_merge_file(
    path: &Path,
    expected_payload: u64,
    limits: &Limits,
    stage: MergeStage,
    tile: Option<usize>,
) -> Result<Vec<u8>, PartialError> {
    let size = match std::fs::metadata(path) {
        Ok(m) => m.len(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(PartialError::Missing {
                stage: stage.to_string(),
                tile,
                path: path.to_path_buf(),
            });
        }
        Err(source) => {
            return Err(PartialError::Io {
                path: path.to_path_buf(),
                source,
            });
        }
    };
    let most = expected_payload.saturating_add(12 + HEADER_MAX);
    if size > most || expected_payload > limits.max_bytes {
        return Err(PartialError::TooLarge {
            path: path.to_path_buf(),
            what: "the file",
            value: size.max(expected_payload),
            limit: most.min(limits.max_bytes),
        });
    }
    std::fs::read(path).map_err(|source| PartialError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes `bytes` to `path` atomically (write, then rename), creating its folder.
pub(crate) fn write_merge_file(path: &Path, bytes: &[u8]) -> Result<(), PartialError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|source| PartialError::Io {
            path: parent.to_path_buf(),
            source,
        })?;
    }
    prt_texture::write_atomic(path, bytes).map_err(|source| PartialError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Little-endian bytes of `values`.
pub(crate) fn le_bytes<T: Copy, const N: usize>(
    values: &[T],
    to: impl Fn(T) -> [u8; N],
) -> Vec<u8> {
    let mut out = Vec::with_capacity(values.len() * N);
    for &v in values {
        out.extend_from_slice(&to(v));
    }
    out
}

/// Little-endian values of `bytes` (a multiple of N long, checked by the caller's size).
pub(crate) fn from_le<T, const N: usize>(bytes: &[u8], from: impl Fn([u8; N]) -> T) -> Vec<T> {
    bytes
        .chunks_exact(N)
        .map(|b| from(b.try_into().unwrap_or([0; N])))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_name_themselves_and_chain() {
        for stage in MergeStage::all(3) {
            assert_eq!(stage.to_string().parse::<MergeStage>().unwrap(), stage);
            stage.check(3).unwrap();
        }
        assert_eq!(MergeStage::all(2).len(), 4);
        assert!("sweep-0".parse::<MergeStage>().is_err());
        assert!("sweep".parse::<MergeStage>().is_err());
        assert!(MergeStage::Sweep(3).check(2).is_err());
        assert_eq!(
            MergeStage::Coefficients.input(2),
            Some(MergeStage::Sweep(2))
        );
        assert_eq!(MergeStage::Coefficients.input(0), Some(MergeStage::Coarse));
        assert_eq!(MergeStage::Sweep(1).input(2), Some(MergeStage::Coarse));
        assert_eq!(MergeStage::Coarse.input(2), None);
        // Fingerprints tell stages, tiles and bases apart.
        let a = partial_fingerprint("p", MergeStage::Sweep(1), 0, "b");
        assert_ne!(a, partial_fingerprint("p", MergeStage::Sweep(2), 0, "b"));
        assert_ne!(a, partial_fingerprint("p", MergeStage::Sweep(1), 1, "b"));
        assert_ne!(a, partial_fingerprint("p", MergeStage::Sweep(1), 0, "c"));
        assert_ne!(a, partial_fingerprint("q", MergeStage::Sweep(1), 0, "b"));
    }
}
