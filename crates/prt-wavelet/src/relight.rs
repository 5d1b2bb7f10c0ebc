//! Wavelet-domain relighting `B = T L` with incremental lighting updates (Overbeck's figure 6.1).
//!
//! The transport `T` (pixels × lighting coefficients, already in the wavelet domain) is
//! truncated per row to its largest entries and quantised to 16 bits as in Ng, Ramamoorthi and
//! Hanrahan (2003). It is stored grouped by column (lighting coefficient), since a frame touches
//! only the columns of its chosen terms. The engine keeps one partial image `B_b = T L̃_b` per
//! band: an incremental band adds `T_i Δ_i` for its new terms only, a replaced band subtracts
//! its old partial image from the total, clears it and rebuilds it from its chosen terms.
//!
//! Every stored entry is a read-modify-write of one pixel in two images (the band's partial
//! image and the total), at a pixel chosen by the transport, so a naive column-by-column apply
//! streams both whole images through the cache once per term. The engine instead works tile by
//! tile: pixels are cut into tiles of [`SparseTransport::tile_rows`] rows (1024 by default:
//! 12 KB per RGB image tile, so a partial tile and the total's tile stay in L1), each column's
//! entries are indexed by tile, and within a tile the terms are applied band by band: a band's
//! terms are summed into one scratch tile (one scattered update of a pixel per stored entry,
//! instead of two), which is then added to the band's partial image and the total in one
//! contiguous pass. The transport bytes read are the same; each image is touched once per band
//! and frame instead of once per term.

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
    tile_rows: usize,
    /// `tile_offsets[j * (tiles + 1) + t]`: first entry of column `j` in pixel tile `t`,
    /// relative to `col_start[j]` (entries of a column are sorted by row).
    tile_offsets: Vec<u32>,
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
        let mut transport = Self {
            rows,
            cols,
            tile_rows: 0,
            tile_offsets: Vec::new(),
            col_start,
            row_index,
            quantised,
            scale,
        };
        transport.index_tiles(Self::DEFAULT_TILE_ROWS);
        Ok(transport)
    }

    /// Pixel rows per tile unless [`Self::with_tile_rows`] says otherwise.
    pub const DEFAULT_TILE_ROWS: usize = 1024;

    /// The same transport with pixel tiles of `tile_rows` rows (clamped to `1..=rows`; `rows`
    /// means one tile, i.e. the plain column-by-column apply). Only the apply's memory traffic
    /// changes, never its result.
    pub fn with_tile_rows(mut self, tile_rows: usize) -> Self {
        self.index_tiles(tile_rows);
        self
    }

    /// Pixel rows per tile.
    pub fn tile_rows(&self) -> usize {
        self.tile_rows
    }

    /// Number of pixel tiles.
    pub fn tiles(&self) -> usize {
        self.rows.div_ceil(self.tile_rows).max(1)
    }

    fn index_tiles(&mut self, tile_rows: usize) {
        self.tile_rows = tile_rows.clamp(1, self.rows.max(1));
        let tiles = self.tiles();
        self.tile_offsets = vec![0; self.cols * (tiles + 1)];
        for j in 0..self.cols {
            let rows = &self.row_index[self.col_start[j]..self.col_start[j + 1]];
            let offsets = &mut self.tile_offsets[j * (tiles + 1)..(j + 1) * (tiles + 1)];
            for (t, o) in offsets.iter_mut().enumerate() {
                // Entries are sorted by row: the first at or past the tile's first row.
                *o = rows.partition_point(|&r| (r as usize) < t * self.tile_rows) as u32;
            }
        }
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

    /// The entries of column `j` in pixel tile `tile`.
    #[inline]
    fn tile_range(&self, j: usize, tile: usize) -> std::ops::Range<usize> {
        let offsets = &self.tile_offsets[j * (self.tiles() + 1) + tile..];
        self.col_start[j] + offsets[0] as usize..self.col_start[j] + offsets[1] as usize
    }

    /// `delta[(r − first_row)·C + c] += v_c T(r, j)` for the entries of column `j` in tile
    /// `tile` (whose first pixel is `first_row`) and all `C` channels at once: one scattered
    /// read-modify-write of `C` adjacent floats per entry.
    #[inline]
    fn add_tile<const C: usize>(&self, j: usize, tile: usize, values: &[f32], delta: &mut [f32]) {
        let range = self.tile_range(j, tile);
        let first_row = tile * self.tile_rows;
        let mut s = [0.0f32; C];
        for c in 0..C {
            s[c] = values[c] * self.scale[j];
        }
        for (&r, &q) in self.row_index[range.clone()]
            .iter()
            .zip(&self.quantised[range])
        {
            let q = q as f32;
            let o = (r as usize - first_row) * C;
            let pixel = &mut delta[o..o + C];
            for c in 0..C {
                pixel[c] += s[c] * q;
            }
        }
    }

    /// [`Self::add_tile`] for a channel count known only at run time.
    fn add_tile_any(&self, j: usize, tile: usize, values: &[f32], delta: &mut [f32]) {
        let range = self.tile_range(j, tile);
        let first_row = tile * self.tile_rows;
        let channels = values.len();
        for (&r, &q) in self.row_index[range.clone()]
            .iter()
            .zip(&self.quantised[range])
        {
            let q = q as f32 * self.scale[j];
            let o = (r as usize - first_row) * channels;
            for (d, v) in delta[o..o + channels].iter_mut().zip(values) {
                *d += v * q;
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
    /// One tile of one band's new contributions (reused every frame).
    delta: Vec<f32>,
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
            channels,
            partial: vec![vec![0.0; n]; bands],
            image: vec![0.0; n],
            delta: vec![0.0; transport.tile_rows * channels],
            transport,
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
        let replaced: Vec<usize> = (0..update.modes.len())
            .filter(|&b| update.modes[b] == BandMode::Replace)
            .collect();
        // Terms grouped by band, so that within a tile one partial image tile is hot at a time.
        let mut order: Vec<usize> = (0..update.terms.len()).collect();
        order.sort_by_key(|&t| update.terms[t].band);
        let c = self.channels;
        let transport = &self.transport;
        for tile in 0..transport.tiles() {
            let first = tile * transport.tile_rows * c;
            let pixels = first..((tile + 1) * transport.tile_rows).min(transport.rows) * c;
            let image = &mut self.image[pixels.clone()];
            for &b in &replaced {
                for (img, p) in image.iter_mut().zip(&mut self.partial[b][pixels.clone()]) {
                    *img -= *p;
                    *p = 0.0;
                }
            }
            // Band by band: the band's new terms are summed into `delta` (scattered, but
            // within one L1-resident tile), then added to its partial image and the total in
            // one contiguous pass.
            let delta = &mut self.delta[..pixels.len()];
            for group in order.chunk_by(|&x, &y| update.terms[x].band == update.terms[y].band) {
                delta.fill(0.0);
                for &t in group {
                    let j = update.terms[t].index as usize;
                    let values = &update.values[t * c..(t + 1) * c];
                    match c {
                        1 => transport.add_tile::<1>(j, tile, values, delta),
                        2 => transport.add_tile::<2>(j, tile, values, delta),
                        3 => transport.add_tile::<3>(j, tile, values, delta),
                        4 => transport.add_tile::<4>(j, tile, values, delta),
                        _ => transport.add_tile_any(j, tile, values, delta),
                    }
                }
                let band = update.terms[group[0]].band as usize;
                for ((p, img), d) in self.partial[band][pixels.clone()]
                    .iter_mut()
                    .zip(image.iter_mut())
                    .zip(delta.iter())
                {
                    *p += d;
                    *img += d;
                }
            }
        }
        let bytes = update
            .terms
            .iter()
            .map(|t| transport.column_bytes(t.index as usize))
            .sum();
        Ok(bytes)
    }
}
