//! The per-pixel transport file (docs/formats.md, "Per-pixel wavelet transport"): written
//! atomically, read with size limits and every field checked.

use std::io::Read;
use std::path::Path;

use glam::Vec3;
use prt_texture::{Limits, write_atomic};
use prt_wavelet::{SparseTransport, TransportParts};

use crate::TraceError;
use crate::camera::PinholeView;

use super::{Bounce, PixelTransport, PixelTransportOptions, Sparsify};

impl PixelTransport {
    /// Writes the transport to `path` atomically (docs/formats.md, "Per-pixel wavelet
    /// transport").
    pub fn write(&self, path: &Path) -> Result<(), TraceError> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        let o = &self.options;
        for v in [
            VERSION,
            o.width as u32,
            o.height as u32,
            o.cube_size as u32,
            o.samples as u32,
            o.sparsify.max_terms as u32,
            o.bounce.map_or(0, |b| b.gathers as u32),
            self.transport.len() as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&o.seed.to_le_bytes());
        let v = &self.view;
        for f in [o.sparsify.energy, o.offset]
            .into_iter()
            .chain(v.position.to_array())
            .chain(v.forward.to_array())
            .chain(v.up.to_array())
            .chain([v.yfov])
        {
            out.extend_from_slice(&f.to_le_bytes());
        }
        for p in 0..self.pixels() {
            out.push(self.hit[p] as u8);
            for f in self.albedo[p].iter().chain(&self.emission[p]) {
                out.extend_from_slice(&f.to_le_bytes());
            }
        }
        for t in &self.transport {
            let parts = t.to_parts();
            out.extend_from_slice(&(parts.rows as u64).to_le_bytes());
            out.extend_from_slice(&(parts.cols as u64).to_le_bytes());
            out.extend_from_slice(&(parts.entry_rows.len() as u64).to_le_bytes());
            for s in &parts.scale {
                out.extend_from_slice(&s.to_le_bytes());
            }
            for s in &parts.col_start {
                out.extend_from_slice(&s.to_le_bytes());
            }
            for r in &parts.entry_rows {
                out.extend_from_slice(&r.to_le_bytes());
            }
            for q in &parts.quantised {
                out.extend_from_slice(&q.to_le_bytes());
            }
        }
        write_atomic(path, &out).map_err(|source| TraceError::Write {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Reads a file written by [`Self::write`]. Errors: [`TraceError::Io`] when it cannot be
    /// read, [`TraceError::BadTransportFile`] naming the first field that is wrong (magic,
    /// version, sizes beyond `limits.max_bytes`, a truncated file, a non-finite value, an
    /// inconsistent transport).
    pub fn read(path: &Path, limits: &Limits) -> Result<Self, TraceError> {
        let bad = |why: String| TraceError::BadTransportFile {
            path: path.to_path_buf(),
            why,
        };
        let file = std::fs::File::open(path).map_err(|source| TraceError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let len = file
            .metadata()
            .map_err(|source| TraceError::Io {
                path: path.to_path_buf(),
                source,
            })?
            .len();
        if len > limits.max_bytes {
            return Err(bad(format!(
                "{len} bytes exceed the limit of {}",
                limits.max_bytes
            )));
        }
        let mut bytes = Vec::with_capacity(len as usize);
        file.take(limits.max_bytes)
            .read_to_end(&mut bytes)
            .map_err(|source| TraceError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        let mut r = Reader {
            bytes: &bytes,
            at: 0,
        };
        if r.take(MAGIC.len()).map_err(&bad)? != MAGIC {
            return Err(bad("not a prt pixel-transport file (bad magic)".into()));
        }
        let version = r.u32().map_err(&bad)?;
        if version != VERSION {
            return Err(bad(format!("version {version}, expected {VERSION}")));
        }
        let mut header = [0u32; 7];
        for h in &mut header {
            *h = r.u32().map_err(&bad)?;
        }
        let [
            width,
            height,
            cube_size,
            samples,
            max_terms,
            gathers,
            channels,
        ] = header.map(|v| v as usize);
        let seed = r.u64().map_err(&bad)?;
        let mut floats = [0f32; 12];
        for f in &mut floats {
            *f = r.f32().map_err(&bad)?;
        }
        if let Some(i) = floats.iter().position(|f| !f.is_finite()) {
            return Err(bad(format!("header float {i} is not finite")));
        }
        if !(channels == 1 || channels == 3) || (channels == 3) != (gathers > 0) {
            return Err(bad(format!(
                "{channels} channels with {gathers} gathers (expected 1 without a bounce, 3 with)"
            )));
        }
        if !cube_size.is_power_of_two() || cube_size > 256 {
            return Err(bad(format!("cube size {cube_size}")));
        }
        let pixels = width
            .checked_mul(height)
            .filter(|&p| (p as u64).saturating_mul(25) <= len)
            .ok_or_else(|| bad(format!("{width} × {height} pixels do not fit the file")))?;
        let options = PixelTransportOptions {
            width,
            height,
            cube_size,
            samples,
            sparsify: Sparsify {
                energy: floats[0],
                max_terms,
            },
            bounce: (gathers > 0).then_some(Bounce { gathers }),
            seed,
            offset: floats[1],
        };
        let v3 = |i: usize| Vec3::new(floats[i], floats[i + 1], floats[i + 2]);
        let view = PinholeView {
            position: v3(2),
            forward: v3(5),
            up: v3(8),
            yfov: floats[11],
        };
        let (mut albedo, mut emission, mut hit) = (
            Vec::with_capacity(pixels),
            Vec::with_capacity(pixels),
            Vec::with_capacity(pixels),
        );
        for p in 0..pixels {
            hit.push(r.take(1).map_err(&bad)?[0] != 0);
            let mut v = [0f32; 6];
            for f in &mut v {
                *f = r.f32().map_err(&bad)?;
            }
            if v.iter().any(|f| !f.is_finite()) {
                return Err(bad(format!("pixel {p}'s albedo or emission is not finite")));
            }
            albedo.push([v[0], v[1], v[2]]);
            emission.push([v[3], v[4], v[5]]);
        }
        let mut transport = Vec::with_capacity(channels);
        for c in 0..channels {
            let rows = r.u64().map_err(&bad)? as usize;
            let cols = r.u64().map_err(&bad)? as usize;
            let nnz = r.u64().map_err(&bad)? as usize;
            if rows != pixels || cols != 6 * cube_size * cube_size {
                return Err(bad(format!(
                    "transport {c} is {rows} × {cols}, expected {pixels} × {}",
                    6 * cube_size * cube_size
                )));
            }
            let needed = (cols as u64) * 12 + 8 + (nnz as u64) * 6;
            if needed > (bytes.len() - r.at) as u64 {
                return Err(bad(format!("transport {c} is truncated")));
            }
            let scale = (0..cols).map(|_| r.f32()).collect::<Result<Vec<_>, _>>();
            let col_start = (0..=cols).map(|_| r.u64()).collect::<Result<Vec<_>, _>>();
            let entry_rows = (0..nnz).map(|_| r.u32()).collect::<Result<Vec<_>, _>>();
            let quantised = (0..nnz)
                .map(|_| r.take(2).map(|b| i16::from_le_bytes([b[0], b[1]])))
                .collect::<Result<Vec<_>, _>>();
            let parts = TransportParts {
                rows,
                cols,
                col_start: col_start.map_err(&bad)?,
                entry_rows: entry_rows.map_err(&bad)?,
                quantised: quantised.map_err(&bad)?,
                scale: scale.map_err(&bad)?,
            };
            transport.push(
                SparseTransport::from_parts(parts)
                    .map_err(|e| bad(format!("transport {c}: {e}")))?,
            );
        }
        if r.at != bytes.len() {
            return Err(bad(format!("{} trailing bytes", bytes.len() - r.at)));
        }
        Ok(Self {
            options,
            view,
            albedo,
            emission,
            hit,
            transport,
        })
    }
}

const MAGIC: &[u8; 8] = b"PRTPIXT\0";
const VERSION: u32 = 1;

/// A cursor over a file's bytes whose reads fail (never panic) past the end.
struct Reader<'b> {
    bytes: &'b [u8],
    at: usize,
}

impl<'b> Reader<'b> {
    fn take(&mut self, n: usize) -> Result<&'b [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| format!("truncated at byte {}", self.at))?;
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self) -> Result<u32, String> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self) -> Result<u64, String> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().map_err(|_| "short read")?))
    }

    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32()?))
    }
}
