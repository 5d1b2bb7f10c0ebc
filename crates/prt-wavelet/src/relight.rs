//! Wavelet-domain relighting `B = T L` with incremental lighting updates (Overbeck's figure 6.1).
//!
//! The transport `T` (pixels × lighting coefficients, already in the wavelet domain) is
//! truncated per row to its largest entries and quantised to 16 bits as in Ng, Ramamoorthi and
//! Hanrahan (2003). It is stored grouped by column (lighting coefficient), since a frame touches
//! only the columns of its chosen terms. The engine keeps one partial image `B_b = T L̃_b` per
//! band: an incremental band adds `T_i Δ_i` for its new terms only, a replaced band subtracts
//! its old partial image from the total, clears it and rebuilds it from its chosen terms.

use prt_core::{MatrixOracle, Progress};

use crate::WaveletError;
use crate::approx::{BandMode, FrameUpdate};

/// A row-truncated, 16-bit-quantised sparse transport matrix stored by column.
///
/// Entry `(r, j)` is `q × scale[j]` with `q` an `i16` and `scale[j] = max_r |T(r, j)| / 32767`,
/// so the quantisation error of an entry is at most `scale[j] / 2`.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseTransport {
    rows: usize,
    cols: usize,
    col_start: Vec<usize>,
    row_index: Vec<u32>,
    quantised: Vec<i16>,
    scale: Vec<f32>,
}

impl SparseTransport {
    /// Reads every row of a scalar (1-channel) oracle, keeps the `keep_per_row` entries of
    /// largest magnitude of each row (exact zeros are never kept) and quantises. Errors: a
    /// multi-channel oracle, more than `u32::MAX` rows, a non-finite entry, oracle errors, or
    /// cancellation through `progress`.
    pub fn from_oracle(
        oracle: &dyn MatrixOracle,
        keep_per_row: usize,
        progress: &dyn Progress,
    ) -> Result<Self, WaveletError> {
        if oracle.channels() != 1 {
            return Err(WaveletError::Invalid {
                what: "transport oracle",
                why: format!(
                    "{} channels; the transport must be scalar",
                    oracle.channels()
                ),
            });
        }
        let (rows, cols) = (oracle.rows(), oracle.cols());
        if rows > u32::MAX as usize {
            return Err(WaveletError::Invalid {
                what: "transport rows",
                why: format!("{rows} > u32::MAX"),
            });
        }
        progress.set_len(rows as u64);
        let mut row = vec![0.0f32; cols];
        let mut order: Vec<u32> = Vec::with_capacity(cols);
        let mut entries: Vec<(u32, u32, f32)> = Vec::new(); // (col, row, value)
        for r in 0..rows {
            if progress.is_cancelled() {
                return Err(WaveletError::Cancelled);
            }
            oracle.eval_row(r, &mut row)?;
            if let Some(i) = row.iter().position(|v| !v.is_finite()) {
                return Err(WaveletError::NonFinite {
                    what: "transport",
                    index: r * cols + i,
                });
            }
            order.clear();
            order.extend((0..cols as u32).filter(|&j| row[j as usize] != 0.0));
            let larger = |a: &u32, b: &u32| {
                row[*b as usize]
                    .abs()
                    .total_cmp(&row[*a as usize].abs())
                    .then(a.cmp(b))
            };
            if order.len() > keep_per_row && keep_per_row > 0 {
                order.select_nth_unstable_by(keep_per_row - 1, larger);
            }
            order.truncate(keep_per_row);
            entries.extend(order.iter().map(|&j| (j, r as u32, row[j as usize])));
            progress.inc(1);
        }
        entries.sort_unstable_by_key(|e| (e.0, e.1));
        let mut scale = vec![0.0f32; cols];
        for &(j, _, v) in &entries {
            scale[j as usize] = scale[j as usize].max(v.abs());
        }
        for s in &mut scale {
            *s /= i16::MAX as f32;
        }
        let mut col_start = vec![0usize; cols + 1];
        for &(j, _, _) in &entries {
            col_start[j as usize + 1] += 1;
        }
        for j in 0..cols {
            col_start[j + 1] += col_start[j];
        }
        let row_index = entries.iter().map(|e| e.1).collect();
        let quantised = entries
            .iter()
            .map(|&(j, _, v)| (v / scale[j as usize]).round().clamp(-32767.0, 32767.0) as i16)
            .collect();
        Ok(Self {
            rows,
            cols,
            col_start,
            row_index,
            quantised,
            scale,
        })
    }

    /// Rows (pixels).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Columns (lighting coefficients).
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Stored entries.
    pub fn nnz(&self) -> usize {
        self.row_index.len()
    }

    /// Bytes read to apply column `j` once (row indices and quantised values).
    pub fn column_bytes(&self, j: usize) -> usize {
        (self.col_start[j + 1] - self.col_start[j]) * (size_of::<u32>() + size_of::<i16>())
    }

    /// The dequantised matrix, dense and row-major (for tests and small examples).
    pub fn to_dense(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.rows * self.cols];
        for j in 0..self.cols {
            for e in self.col_start[j]..self.col_start[j + 1] {
                out[self.row_index[e] as usize * self.cols + j] =
                    self.quantised[e] as f32 * self.scale[j];
            }
        }
        out
    }

    /// L1 norm of every dequantised column: Ng et al.'s transport weights for lighting selection
    /// (pass as [`crate::Weighting::Transport`]).
    pub fn column_l1_norms(&self) -> Vec<f32> {
        (0..self.cols)
            .map(|j| {
                let s: f64 = self.quantised[self.col_start[j]..self.col_start[j + 1]]
                    .iter()
                    .map(|&q| (q as f64).abs())
                    .sum();
                (s * self.scale[j] as f64) as f32
            })
            .collect()
    }

    /// `partial[r·C + c] += v_c T(r, j)` and the same into `image`, for every stored entry of
    /// column `j` and all `C` channels at once (the column is decoded once per term, and each
    /// entry touches one pixel of each image).
    #[inline]
    fn add_column<const C: usize>(
        &self,
        j: usize,
        values: &[f32],
        partial: &mut [f32],
        image: &mut [f32],
    ) {
        let range = self.col_start[j]..self.col_start[j + 1];
        let mut s = [0.0f32; C];
        for c in 0..C {
            s[c] = values[c] * self.scale[j];
        }
        for (&r, &q) in self.row_index[range.clone()]
            .iter()
            .zip(&self.quantised[range])
        {
            let q = q as f32;
            for c in 0..C {
                let o = r as usize * C + c;
                partial[o] += s[c] * q;
                image[o] += s[c] * q;
            }
        }
    }
}

impl SparseTransport {
    /// [`Self::add_column`] for a channel count known only at run time.
    fn add_column_any(&self, j: usize, values: &[f32], partial: &mut [f32], image: &mut [f32]) {
        let range = self.col_start[j]..self.col_start[j + 1];
        let channels = values.len();
        for (&r, &q) in self.row_index[range.clone()]
            .iter()
            .zip(&self.quantised[range])
        {
            let q = q as f32 * self.scale[j];
            for (c, v) in values.iter().enumerate() {
                let o = r as usize * channels + c;
                partial[o] += v * q;
                image[o] += v * q;
            }
        }
    }
}

/// The incremental relighting engine: applies [`FrameUpdate`]s to per-band partial images.
#[derive(Debug, Clone)]
pub struct Relighter {
    transport: SparseTransport,
    channels: usize,
    /// `partial[b][r * channels + c]`.
    partial: Vec<Vec<f32>>,
    /// `image[r * channels + c]` = Σ_b partial[b].
    image: Vec<f32>,
}

impl Relighter {
    /// An engine for `channels` lighting channels and `bands` bands, starting from `L̃ = 0`.
    pub fn new(
        transport: SparseTransport,
        channels: usize,
        bands: usize,
    ) -> Result<Self, WaveletError> {
        if channels == 0 || bands == 0 {
            return Err(WaveletError::Invalid {
                what: "relighter",
                why: "needs channels and bands".into(),
            });
        }
        let n = transport.rows * channels;
        Ok(Self {
            transport,
            channels,
            partial: vec![vec![0.0; n]; bands],
            image: vec![0.0; n],
        })
    }

    /// The transport.
    pub fn transport(&self) -> &SparseTransport {
        &self.transport
    }

    /// The image `B = T L̃`, pixel-major (`image[r * channels + c]`).
    pub fn image(&self) -> &[f32] {
        &self.image
    }

    /// Applies one frame's update; returns the bytes of transport columns read (each chosen
    /// column once, for all channels; for comparing the frame's time with the memory-bandwidth
    /// bound). Errors if the update does not fit the
    /// engine (band count, channel count, a term's index or band out of range).
    pub fn apply(&mut self, update: &FrameUpdate) -> Result<usize, WaveletError> {
        WaveletError::check_len("update bands", self.partial.len(), update.modes.len())?;
        WaveletError::check_len(
            "update values",
            update.terms.len() * self.channels,
            update.values.len(),
        )?;
        if let Some(t) = update.terms.iter().find(|t| {
            t.index as usize >= self.transport.cols || t.band as usize >= self.partial.len()
        }) {
            return Err(WaveletError::Invalid {
                what: "update term",
                why: format!(
                    "coefficient {} (band {}) outside the engine",
                    t.index, t.band
                ),
            });
        }
        for (b, mode) in update.modes.iter().enumerate() {
            if *mode == BandMode::Replace {
                for (img, p) in self.image.iter_mut().zip(&mut self.partial[b]) {
                    *img -= *p;
                    *p = 0.0;
                }
            }
        }
        let mut bytes = 0;
        for (t, term) in update.terms.iter().enumerate() {
            let j = term.index as usize;
            bytes += self.transport.column_bytes(j);
            let partial = &mut self.partial[term.band as usize];
            let values = &update.values[t * self.channels..(t + 1) * self.channels];
            match self.channels {
                1 => self
                    .transport
                    .add_column::<1>(j, values, partial, &mut self.image),
                3 => self
                    .transport
                    .add_column::<3>(j, values, partial, &mut self.image),
                2 => self
                    .transport
                    .add_column::<2>(j, values, partial, &mut self.image),
                4 => self
                    .transport
                    .add_column::<4>(j, values, partial, &mut self.image),
                _ => self
                    .transport
                    .add_column_any(j, values, partial, &mut self.image),
            }
        }
        Ok(bytes)
    }
}
