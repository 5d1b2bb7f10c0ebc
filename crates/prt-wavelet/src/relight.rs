//! Wavelet-domain relighting `B = T L` with incremental lighting updates (Overbeck's figure 6.1).
//!
//! The transport `T` (pixels × lighting coefficients, already in the wavelet domain) is
//! truncated per row to its largest entries and quantised to 16 bits as in Ng, Ramamoorthi and
//! Hanrahan (2003). It is stored by column (lighting coefficient), since a frame touches only
//! the columns of its chosen terms: a term reads one contiguous run of entries. The engine keeps
//! one partial image `B_b = T L̃_b` per band: an incremental band adds `T_i Δ_i` for its new
//! terms only, a replaced band subtracts its old partial image from the total, clears it and
//! rebuilds it from its chosen terms.
//!
//! Layout, chosen for the memory traffic of one frame:
//! - Pixels are cut into tiles of [`SparseTransport::tile_rows`] rows (1024 by default, at most
//!   65 536), and each column's entries are grouped by tile. An entry is 4 bytes: its row
//!   *within the tile* (`u16`) and its quantised value (`i16`), read with one load.
//! - The partial images are stored tile-major (all bands' partial tiles of one pixel tile are
//!   adjacent), so the tiles are independent and are processed in parallel (rayon); a tile's
//!   image and partial tiles stay in cache while all of the frame's terms are applied to it.
//! - Within a tile the terms are applied band by band. A band whose terms hold few entries
//!   (under a quarter of the pixels) scatters them straight into its partial image and the
//!   total; a band with many sums them into a scratch tile first (one scattered update per
//!   entry instead of two) and adds that to both images in one contiguous pass.
//! - Images store pixels of up to four channels padded to four floats, so that an RGB update
//!   is one vector multiply-add and the image passes vectorise. The choice is
//!   made per band and frame from the whole columns' sizes, never per tile, so the result is
//!   bit-identical for every tile size and thread count.

use prt_core::{MatrixOracle, Progress};
use rayon::prelude::*;

use crate::WaveletError;
use crate::approx::{BandMode, FrameUpdate};

/// One stored transport entry: its pixel relative to the first pixel of its tile and its
/// quantised value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C, align(4))]
struct Entry {
    row: u16,
    q: i16,
}

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
    entries: Vec<Entry>,
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
        let mut kept: Vec<Vec<(u32, f32)>> = Vec::with_capacity(rows);
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
            order.sort_unstable();
            kept.push(order.iter().map(|&j| (j, row[j as usize])).collect());
            progress.inc(1);
        }
        Self::from_sparse_rows(cols, &kept)
    }

    /// Quantises already-truncated rows: `rows[r]` lists row `r`'s kept entries as
    /// `(column, value)` with distinct columns in any order (exact zeros are dropped). Use it
    /// when the rows were computed in parallel (e.g. per-pixel transport traced over rayon).
    /// Errors: a column out of range or repeated, a non-finite value, or more than `u32::MAX`
    /// rows or entries.
    pub fn from_sparse_rows(cols: usize, rows: &[Vec<(u32, f32)>]) -> Result<Self, WaveletError> {
        if rows.len() > u32::MAX as usize {
            return Err(WaveletError::Invalid {
                what: "transport rows",
                why: format!("{} > u32::MAX", rows.len()),
            });
        }
        // Pass 1: entries and largest magnitude per column.
        let mut col_start = vec![0usize; cols + 1];
        let mut scale = vec![0.0f32; cols];
        let mut seen = vec![u32::MAX; cols];
        for (r, row) in rows.iter().enumerate() {
            for (k, &(j, v)) in row.iter().enumerate() {
                let ju = j as usize;
                if ju >= cols {
                    return Err(WaveletError::Invalid {
                        what: "transport row",
                        why: format!("row {r} names column {j} of {cols}"),
                    });
                }
                if !v.is_finite() {
                    return Err(WaveletError::NonFinite {
                        what: "transport row",
                        index: r * cols + ju,
                    });
                }
                if seen[ju] == r as u32 {
                    return Err(WaveletError::Invalid {
                        what: "transport row",
                        why: format!("row {r} repeats column {j} (entry {k})"),
                    });
                }
                seen[ju] = r as u32;
                if v != 0.0 {
                    col_start[ju + 1] += 1;
                    scale[ju] = scale[ju].max(v.abs());
                }
            }
        }
        for j in 0..cols {
            col_start[j + 1] += col_start[j];
        }
        let nnz = col_start[cols];
        if nnz > u32::MAX as usize {
            return Err(WaveletError::Invalid {
                what: "transport entries",
                why: format!("{nnz} > u32::MAX"),
            });
        }
        for s in &mut scale {
            *s /= i16::MAX as f32;
        }
        // Pass 2: rows visited in order, so every column's entries come out sorted by row.
        let mut fill = col_start[..cols].to_vec();
        let mut global_rows = vec![0u32; nnz];
        let mut quantised = vec![0i16; nnz];
        for (r, row) in rows.iter().enumerate() {
            for &(j, v) in row.iter().filter(|e| e.1 != 0.0) {
                let at = fill[j as usize];
                fill[j as usize] += 1;
                global_rows[at] = r as u32;
                quantised[at] = quantise(v, scale[j as usize]);
            }
        }
        let mut transport = Self {
            rows: rows.len(),
            cols,
            tile_rows: 0,
            tile_offsets: Vec::new(),
            col_start,
            entries: Vec::new(),
            scale,
        };
        transport.index_tiles(Self::DEFAULT_TILE_ROWS, &global_rows, &quantised);
        Ok(transport)
    }

    /// The stored form, for writing to a file: every column's entries (global row, quantised
    /// value) in column order, the entry offset of each column and its scale.
    pub fn to_parts(&self) -> TransportParts {
        let (rows, quantised) = self.global_entries();
        TransportParts {
            rows: self.rows,
            cols: self.cols,
            col_start: self.col_start.iter().map(|&s| s as u64).collect(),
            entry_rows: rows,
            quantised,
            scale: self.scale.clone(),
        }
    }

    /// Rebuilds a transport from [`Self::to_parts`] (e.g. read from a file, so everything is
    /// checked): `col_start` non-decreasing from 0 to the entry count, rows in range and
    /// strictly increasing within a column, finite non-negative scales. Errors name the first
    /// violation.
    pub fn from_parts(parts: TransportParts) -> Result<Self, WaveletError> {
        let TransportParts {
            rows,
            cols,
            col_start,
            entry_rows,
            quantised,
            scale,
        } = parts;
        let invalid = |why: String| WaveletError::Invalid {
            what: "transport parts",
            why,
        };
        WaveletError::check_len("transport column offsets", cols + 1, col_start.len())?;
        WaveletError::check_len("transport scales", cols, scale.len())?;
        WaveletError::check_len("transport entries", entry_rows.len(), quantised.len())?;
        if rows > u32::MAX as usize {
            return Err(invalid(format!("{rows} rows > u32::MAX")));
        }
        if col_start[0] != 0 || col_start[cols] != entry_rows.len() as u64 {
            return Err(invalid(format!(
                "column offsets run from {} to {}, not 0 to {}",
                col_start[0],
                col_start[cols],
                entry_rows.len()
            )));
        }
        if let Some(j) = scale.iter().position(|s| !s.is_finite() || *s < 0.0) {
            return Err(invalid(format!("column {j} has scale {}", scale[j])));
        }
        for j in 0..cols {
            if col_start[j + 1] < col_start[j] {
                return Err(invalid(format!("column {j} ends before it starts")));
            }
            let run = &entry_rows[col_start[j] as usize..col_start[j + 1] as usize];
            if let Some(k) = run.iter().position(|&r| r as usize >= rows) {
                return Err(invalid(format!(
                    "column {j} names row {} of {rows}",
                    run[k]
                )));
            }
            if run.windows(2).any(|w| w[0] >= w[1]) {
                return Err(invalid(format!("column {j}'s rows are not increasing")));
            }
        }
        let mut transport = Self {
            rows,
            cols,
            tile_rows: 0,
            tile_offsets: Vec::new(),
            col_start: col_start.iter().map(|&s| s as usize).collect(),
            entries: Vec::new(),
            scale,
        };
        transport.index_tiles(Self::DEFAULT_TILE_ROWS, &entry_rows, &quantised);
        Ok(transport)
    }

    /// Pixel rows per tile unless [`Self::with_tile_rows`] says otherwise.
    pub const DEFAULT_TILE_ROWS: usize = 1024;

    /// The largest tile: an entry stores its row within the tile in 16 bits.
    pub const MAX_TILE_ROWS: usize = 1 << 16;

    /// The same transport with pixel tiles of `tile_rows` rows (clamped to
    /// `1..=min(rows, MAX_TILE_ROWS)`; `rows` means one tile, i.e. the plain column-by-column
    /// apply, when the image has at most [`Self::MAX_TILE_ROWS`] pixels). Only the apply's
    /// memory traffic and parallelism change, never its result.
    pub fn with_tile_rows(mut self, tile_rows: usize) -> Self {
        let (rows, quantised) = self.global_entries();
        self.index_tiles(tile_rows, &rows, &quantised);
        self
    }

    /// Every entry's global row and quantised value, in storage order.
    fn global_entries(&self) -> (Vec<u32>, Vec<i16>) {
        let tiles = self.tiles();
        let mut rows = Vec::with_capacity(self.entries.len());
        for j in 0..self.cols {
            for t in 0..tiles {
                let first = (t * self.tile_rows) as u32;
                rows.extend(
                    self.entries[self.tile_range(j, t)]
                        .iter()
                        .map(|e| first + e.row as u32),
                );
            }
        }
        (rows, self.entries.iter().map(|e| e.q).collect())
    }

    /// Rebuilds the tile index and the tile-relative entries from `rows` (global, sorted
    /// within each column) and `quantised`.
    fn index_tiles(&mut self, tile_rows: usize, rows: &[u32], quantised: &[i16]) {
        self.tile_rows = tile_rows.clamp(1, self.rows.clamp(1, Self::MAX_TILE_ROWS));
        let tiles = self.tiles();
        self.tile_offsets = vec![0; self.cols * (tiles + 1)];
        for j in 0..self.cols {
            let rows = &rows[self.col_start[j]..self.col_start[j + 1]];
            let offsets = &mut self.tile_offsets[j * (tiles + 1)..(j + 1) * (tiles + 1)];
            for (t, o) in offsets.iter_mut().enumerate() {
                // Entries are sorted by row: the first at or past the tile's first row.
                *o = rows.partition_point(|&r| (r as usize) < t * self.tile_rows) as u32;
            }
        }
        self.entries = rows
            .iter()
            .zip(quantised)
            .map(|(&r, &q)| Entry {
                row: (r as usize % self.tile_rows) as u16,
                q,
            })
            .collect();
    }

    /// Rows (pixels).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Columns (lighting coefficients).
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Pixel rows per tile.
    pub fn tile_rows(&self) -> usize {
        self.tile_rows
    }

    /// Number of pixel tiles.
    pub fn tiles(&self) -> usize {
        self.rows.div_ceil(self.tile_rows).max(1)
    }

    /// Stored entries.
    pub fn nnz(&self) -> usize {
        self.entries.len()
    }

    /// Stored entries of column `j`.
    fn column_len(&self, j: usize) -> usize {
        self.col_start[j + 1] - self.col_start[j]
    }

    /// Bytes read to apply column `j` once (4 per entry: tile-relative row and quantised value).
    pub fn column_bytes(&self, j: usize) -> usize {
        self.column_len(j) * size_of::<Entry>()
    }

    /// The dequantised matrix, dense and row-major (for tests and small examples).
    pub fn to_dense(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.rows * self.cols];
        for j in 0..self.cols {
            for t in 0..self.tiles() {
                for e in &self.entries[self.tile_range(j, t)] {
                    let r = t * self.tile_rows + e.row as usize;
                    out[r * self.cols + j] = e.q as f32 * self.scale[j];
                }
            }
        }
        out
    }

    /// L1 norm of every dequantised column: Ng et al.'s transport weights for lighting selection
    /// (pass as [`crate::Weighting::Transport`]).
    pub fn column_l1_norms(&self) -> Vec<f32> {
        (0..self.cols)
            .map(|j| {
                let s: f64 = self.entries[self.col_start[j]..self.col_start[j + 1]]
                    .iter()
                    .map(|e| (e.q as f64).abs())
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

    /// `out[row] += s · q(row, j)` over the entries of column `j` in tile `tile` (rows relative
    /// to the tile) and every image of `out`, whose pixels are padded to four floats: one
    /// vector load, multiply-add and store per entry and image.
    #[inline]
    fn scatter_padded<const IMAGES: usize>(
        &self,
        j: usize,
        tile: usize,
        s: [f32; 4],
        mut out: [&mut [[f32; 4]]; IMAGES],
    ) {
        for e in &self.entries[self.tile_range(j, tile)] {
            let q = e.q as f32;
            for img in out.iter_mut() {
                let pixel = &mut img[e.row as usize];
                for c in 0..4 {
                    pixel[c] += s[c] * q;
                }
            }
        }
    }

    /// [`Self::scatter_padded`] for more than four channels (`values.len()` floats per pixel).
    fn scatter_flat<const IMAGES: usize>(
        &self,
        j: usize,
        tile: usize,
        values: &[f32],
        mut out: [&mut [f32]; IMAGES],
    ) {
        let channels = values.len();
        for e in &self.entries[self.tile_range(j, tile)] {
            let q = e.q as f32 * self.scale[j];
            let o = e.row as usize * channels;
            for img in out.iter_mut() {
                for (d, v) in img[o..o + channels].iter_mut().zip(values) {
                    *d += v * q;
                }
            }
        }
    }

    /// Adds the terms `(column, term)` of tile `tile` into every image of `out` (pixels of
    /// [`pixel_stride`]`(channels)` floats; `values[term · channels + c]`).
    fn scatter_terms<const IMAGES: usize>(
        &self,
        tile: usize,
        channels: usize,
        terms: impl Iterator<Item = (usize, usize)>,
        values: &[f32],
        mut out: [&mut [f32]; IMAGES],
    ) {
        for (j, t) in terms {
            let v = &values[t * channels..(t + 1) * channels];
            if channels <= 4 {
                let mut s = [0.0f32; 4];
                for (s, v) in s.iter_mut().zip(v) {
                    *s = v * self.scale[j];
                }
                let out = out.each_mut().map(|o| o.as_chunks_mut::<4>().0);
                self.scatter_padded(j, tile, s, out);
            } else {
                self.scatter_flat(j, tile, v, out.each_mut().map(|o| &mut **o));
            }
        }
    }
}

/// `v / scale` rounded to 16 bits (`scale = max |v| / 32767` of the column).
fn quantise(v: f32, scale: f32) -> i16 {
    (v / scale).round().clamp(-32767.0, 32767.0) as i16
}

/// A [`SparseTransport`] in its stored form ([`SparseTransport::to_parts`],
/// [`SparseTransport::from_parts`]): entry `k` of column `j` (`col_start[j] <= k <
/// col_start[j + 1]`) is `quantised[k] × scale[j]` at row `entry_rows[k]`.
#[derive(Debug, Clone, PartialEq)]
pub struct TransportParts {
    /// Rows (pixels).
    pub rows: usize,
    /// Columns (lighting coefficients).
    pub cols: usize,
    /// First entry of every column, and the entry count last (`cols + 1` offsets).
    pub col_start: Vec<u64>,
    /// Row of every entry, increasing within a column.
    pub entry_rows: Vec<u32>,
    /// Quantised value of every entry.
    pub quantised: Vec<i16>,
    /// Dequantisation scale of every column.
    pub scale: Vec<f32>,
}

/// Floats per stored pixel: up to four channels are padded to four (an RGB update is one
/// vector multiply-add, and the image passes vectorise), more are stored as they are.
fn pixel_stride(channels: usize) -> usize {
    if channels <= 4 { 4 } else { channels }
}

/// The incremental relighting engine: applies [`FrameUpdate`]s to per-band partial images.
#[derive(Debug, Clone)]
pub struct Relighter {
    transport: SparseTransport,
    channels: usize,
    bands: usize,
    /// Floats per stored pixel ([`pixel_stride`]).
    stride: usize,
    /// `image[r * stride + c]` = Σ_b B_b.
    image: Vec<f32>,
    /// Partial images, tile-major: tile `t`, band `b` starts at `(t · bands + b) · tile_len`
    /// with `tile_len = tile_rows · stride` (the last tile padded).
    partial: Vec<f32>,
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
        let stride = pixel_stride(channels);
        let tile_len = transport.tile_rows * stride;
        Ok(Self {
            channels,
            bands,
            stride,
            image: vec![0.0; transport.rows * stride],
            partial: vec![0.0; transport.tiles() * bands * tile_len],
            transport,
        })
    }

    /// The transport.
    pub fn transport(&self) -> &SparseTransport {
        &self.transport
    }

    /// A copy of the image `B = T L̃`, pixel-major (`image[r * channels + c]`). (Stored with
    /// pixels padded to four floats; [`Self::image_into`] fills a caller's buffer instead.)
    pub fn image(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.transport.rows * self.channels];
        self.copy_pixels(&self.image, &mut out);
        out
    }

    /// Writes the image `B = T L̃` into `out` (pixel-major, `rows × channels` floats). Errors
    /// on a length mismatch.
    pub fn image_into(&self, out: &mut [f32]) -> Result<(), WaveletError> {
        WaveletError::check_len(
            "image buffer",
            self.transport.rows * self.channels,
            out.len(),
        )?;
        self.copy_pixels(&self.image, out);
        Ok(())
    }

    /// Band `band`'s partial image `B_b = T L̃_b`, pixel-major like [`Self::image`]. Errors if
    /// `band` is out of range.
    pub fn partial_image(&self, band: usize) -> Result<Vec<f32>, WaveletError> {
        if band >= self.bands {
            return Err(WaveletError::Invalid {
                what: "band",
                why: format!("{band} of {}", self.bands),
            });
        }
        let tile_len = self.transport.tile_rows * self.stride;
        let stored: Vec<f32> = self
            .partial
            .chunks_exact(self.bands * tile_len)
            .flat_map(|tile| &tile[band * tile_len..(band + 1) * tile_len])
            .take(self.image.len())
            .copied()
            .collect();
        let mut out = vec![0.0; self.transport.rows * self.channels];
        self.copy_pixels(&stored, &mut out);
        Ok(out)
    }

    /// Drops the padding of stored pixels.
    fn copy_pixels(&self, stored: &[f32], out: &mut [f32]) {
        for (o, p) in out
            .chunks_exact_mut(self.channels)
            .zip(stored.chunks_exact(self.stride))
        {
            o.copy_from_slice(&p[..self.channels]);
        }
    }

    /// Applies one frame's update; returns the bytes of transport columns read (each chosen
    /// column once, for all channels; for comparing the frame's time with the memory-bandwidth
    /// bound). Pixel tiles run in parallel on the rayon pool; the image is the same on any
    /// number of threads. Errors if the update does not fit the engine (band count, channel
    /// count, a term's index or band out of range).
    pub fn apply(&mut self, update: &FrameUpdate) -> Result<usize, WaveletError> {
        WaveletError::check_len("update bands", self.bands, update.modes.len())?;
        WaveletError::check_len(
            "update values",
            update.terms.len() * self.channels,
            update.values.len(),
        )?;
        if let Some(t) = update
            .terms
            .iter()
            .find(|t| t.index as usize >= self.transport.cols || t.band as usize >= self.bands)
        {
            return Err(WaveletError::Invalid {
                what: "update term",
                why: format!(
                    "coefficient {} (band {}) outside the engine",
                    t.index, t.band
                ),
            });
        }
        let transport = &self.transport;
        let replaced: Vec<usize> = (0..self.bands)
            .filter(|&b| update.modes[b] == BandMode::Replace)
            .collect();
        // Terms grouped by band, so that within a tile one partial image tile is hot at a time;
        // per group, whether it goes through the scratch tile (decided on whole columns, so
        // that every tiling adds the same numbers in the same order).
        let mut order: Vec<usize> = (0..update.terms.len()).collect();
        order.sort_by_key(|&t| update.terms[t].band);
        let groups: Vec<(&[usize], bool)> = order
            .chunk_by(|&x, &y| update.terms[x].band == update.terms[y].band)
            .map(|group| {
                let entries: usize = group
                    .iter()
                    .map(|&t| transport.column_len(update.terms[t].index as usize))
                    .sum();
                (group, 4 * entries > transport.rows)
            })
            .collect();
        let (c, bands) = (self.channels, self.bands);
        let tile_len = transport.tile_rows * self.stride;
        self.image
            .par_chunks_mut(tile_len)
            .zip(self.partial.par_chunks_mut(bands * tile_len))
            .enumerate()
            .for_each_init(
                || vec![0.0f32; tile_len],
                |scratch, (tile, (image, partials))| {
                    let n = image.len();
                    for &b in &replaced {
                        let p = &mut partials[b * tile_len..b * tile_len + n];
                        for (img, p) in image.iter_mut().zip(p) {
                            *img -= *p;
                            *p = 0.0;
                        }
                    }
                    for &(group, via_scratch) in &groups {
                        let band = update.terms[group[0]].band as usize;
                        let partial = &mut partials[band * tile_len..band * tile_len + n];
                        let terms = group.iter().map(|&t| (update.terms[t].index as usize, t));
                        if via_scratch {
                            let delta = &mut scratch[..n];
                            delta.fill(0.0);
                            transport.scatter_terms(tile, c, terms, &update.values, [delta]);
                            for ((p, img), d) in
                                partial.iter_mut().zip(image.iter_mut()).zip(delta.iter())
                            {
                                *p += d;
                                *img += d;
                            }
                        } else {
                            transport.scatter_terms(
                                tile,
                                c,
                                terms,
                                &update.values,
                                [partial, &mut *image],
                            );
                        }
                    }
                },
            );
        let bytes = update
            .terms
            .iter()
            .map(|t| transport.column_bytes(t.index as usize))
            .sum();
        Ok(bytes)
    }
}
