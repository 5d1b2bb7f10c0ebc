use prt_core::{MatrixOracle, Progress};
use rand::Rng;
use rayon::prelude::*;

use crate::ManyLightError;

/// Rows evaluated together (in parallel) before they are scattered into the reduced columns;
/// bounds the temporary memory to this many full rows.
const ROW_BATCH: usize = 16;

/// The reduced matrix of row-column sampling: a few sampled rows of the pixels × lights matrix,
/// stored by column, so that reduced column `ρ_j` (the contribution of light `j` to the sampled
/// pixels, all channels) is contiguous.
///
/// Reduced column `j` has `dim = rows × channels` entries: row `r`, channel `c` at `r * channels + c`.
/// Its Euclidean norm `‖ρ_j‖` is kept in f64.
#[derive(Debug, Clone, PartialEq)]
pub struct ReducedMatrix {
    rows: Vec<usize>,
    channels: usize,
    dim: usize,
    data: Vec<f32>,
    norms: Vec<f64>,
}

/// One row index drawn uniformly from each of `count` contiguous strata of `0..total`
/// (stratum `s` is `[s·total/count, (s+1)·total/count)`), so the sampled pixels spread over the
/// image. With `count > total` some strata are empty and their rows repeat a neighbour's; with
/// `total == 0` the result is empty.
pub fn stratified_rows(total: usize, count: usize, rng: &mut impl Rng) -> Vec<usize> {
    if total == 0 {
        return Vec::new();
    }
    (0..count)
        .map(|s| {
            let lo = (s as u128 * total as u128 / count as u128) as usize;
            let hi = ((s as u128 + 1) * total as u128 / count as u128) as usize;
            rng.random_range(lo..hi.max(lo + 1))
        })
        .collect()
}

/// Checks a slice returned by the oracle: `Err(NonFinite)` naming the element of the first
/// non-finite value. `element(k)` maps the slice's element index to (row, col).
fn check_finite(
    values: &[f32],
    channels: usize,
    element: impl Fn(usize) -> (usize, usize),
) -> Result<(), ManyLightError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(k) => {
            let (row, col) = element(k / channels);
            Err(ManyLightError::NonFinite {
                row,
                col,
                channel: k % channels,
            })
        }
        None => Ok(()),
    }
}

/// Validates requested sample counts: each entry is `(name when zero, name when too many,
/// requested, available)`, giving `ZeroSamples` for a zero request and `TooMany` above what is
/// available.
pub(crate) fn check_requests(
    requests: &[(&'static str, &'static str, usize, usize)],
) -> Result<(), ManyLightError> {
    for &(zero, what, requested, available) in requests {
        if requested == 0 {
            return Err(ManyLightError::ZeroSamples { what: zero });
        }
        if requested > available {
            return Err(ManyLightError::TooMany {
                what,
                requested,
                available,
            });
        }
    }
    Ok(())
}

/// Validates the shape of the oracle: `Err(EmptyMatrix)` for zero rows, columns or channels.
pub(crate) fn check_shape(oracle: &dyn MatrixOracle) -> Result<(), ManyLightError> {
    if oracle.rows() == 0 {
        return Err(ManyLightError::EmptyMatrix {
            what: "rows (pixels)",
        });
    }
    if oracle.cols() == 0 {
        return Err(ManyLightError::EmptyMatrix {
            what: "columns (lights)",
        });
    }
    if oracle.channels() == 0 {
        return Err(ManyLightError::EmptyMatrix { what: "channels" });
    }
    Ok(())
}

/// Evaluates column `j` of the oracle into `out`, checking it is finite.
pub(crate) fn eval_column(
    oracle: &dyn MatrixOracle,
    j: usize,
    out: &mut [f32],
) -> Result<(), ManyLightError> {
    oracle.eval_col(j, out)?;
    check_finite(out, oracle.channels(), |i| (i, j))
}

impl ReducedMatrix {
    /// Evaluates `rows` of `oracle` (rows in parallel) and stores them by column.
    ///
    /// Errors: an empty matrix, no rows, a row index out of range
    /// ([`ManyLightError::TooMany`]), a non-finite element ([`ManyLightError::NonFinite`]), a
    /// reduced matrix whose size overflows ([`ManyLightError::TooLarge`]), oracle failures and
    /// cancellation.
    pub fn sample(
        oracle: &dyn MatrixOracle,
        rows: Vec<usize>,
        progress: &dyn Progress,
    ) -> Result<ReducedMatrix, ManyLightError> {
        check_shape(oracle)?;
        if rows.is_empty() {
            return Err(ManyLightError::ZeroSamples { what: "row" });
        }
        let (n, m, channels) = (oracle.rows(), oracle.cols(), oracle.channels());
        if let Some(&bad) = rows.iter().find(|&&i| i >= n) {
            return Err(ManyLightError::TooMany {
                what: "rows",
                requested: bad + 1,
                available: n,
            });
        }
        let too_large = ManyLightError::TooLarge {
            rows: rows.len(),
            channels,
            cols: m,
        };
        let dim = rows.len().checked_mul(channels).ok_or(too_large.clone())?;
        let len = m.checked_mul(dim).ok_or(too_large)?;
        let mut data = vec![0.0f32; len];
        progress.set_len(rows.len() as u64);
        for (batch_index, batch) in rows.chunks(ROW_BATCH).enumerate() {
            progress.check()?;
            let evaluated: Vec<Result<Vec<f32>, ManyLightError>> = batch
                .par_iter()
                .map(|&i| {
                    let mut row = vec![0.0f32; m * channels];
                    oracle.eval_row(i, &mut row)?;
                    check_finite(&row, channels, |j| (i, j))?;
                    Ok(row)
                })
                .collect();
            for (t, row) in evaluated.into_iter().enumerate() {
                let row = row?;
                let offset = (batch_index * ROW_BATCH + t) * channels;
                for (j, element) in row.chunks_exact(channels).enumerate() {
                    data[j * dim + offset..j * dim + offset + channels].copy_from_slice(element);
                }
            }
            progress.inc(batch.len() as u64);
        }
        let norms = data
            .par_chunks(dim)
            .map(|col| col.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt())
            .collect();
        Ok(ReducedMatrix {
            rows,
            channels,
            dim,
            data,
            norms,
        })
    }

    /// The reduced matrix restricted to some of its sampled rows: `positions` index
    /// [`ReducedMatrix::rows`] (positions out of range are skipped). No oracle call.
    pub fn select_rows(&self, positions: &[usize]) -> ReducedMatrix {
        let positions: Vec<usize> = positions
            .iter()
            .copied()
            .filter(|&p| p < self.rows.len())
            .collect();
        let channels = self.channels;
        let dim = positions.len() * channels;
        // Entry offsets into a full reduced column, in the order of the selected column.
        let offsets: Vec<usize> = positions
            .iter()
            .flat_map(|&p| p * channels..(p + 1) * channels)
            .collect();
        let mut data = vec![0.0f32; self.cols() * dim];
        let mut norms = vec![0.0f64; self.cols()];
        if dim > 0 {
            for (j, (dst, norm)) in data.chunks_exact_mut(dim).zip(&mut norms).enumerate() {
                // A zero column stays zero on any subset of its rows (most lights of a scene
                // whose view sees little of the lit geometry): nothing to copy.
                if self.norms[j] == 0.0 {
                    continue;
                }
                let src = self.column(j);
                for (d, &o) in dst.iter_mut().zip(&offsets) {
                    *d = src[o];
                }
                *norm = dst.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt();
            }
        }
        let rows = positions.iter().map(|&p| self.rows[p]).collect();
        ReducedMatrix {
            rows,
            channels,
            dim,
            data,
            norms,
        }
    }

    /// The sampled row indices, in the order of the reduced columns' entries.
    pub fn rows(&self) -> &[usize] {
        &self.rows
    }

    /// Number of columns (lights).
    pub fn cols(&self) -> usize {
        self.norms.len()
    }

    /// Values per element.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Length of a reduced column (`rows × channels`).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Reduced column `j`, or an empty slice if `j` is out of range.
    pub fn column(&self, j: usize) -> &[f32] {
        self.data
            .get(j * self.dim..(j + 1) * self.dim)
            .unwrap_or(&[])
    }

    /// `‖ρ_j‖` for every column.
    pub fn norms(&self) -> &[f64] {
        &self.norms
    }
}
