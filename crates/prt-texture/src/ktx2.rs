//! KTX 2.0 writer and reader (Khronos KTX 2.0 specification, data format descriptors per the
//! Khronos Data Format Specification 1.3).
//!
//! File layout written ([`Ktx2Texture::to_bytes`]), all little-endian:
//!
//! ```text
//! 0      identifier «KTX 20»\r\n\x1A\n (12 bytes)
//! 12     vkFormat, typeSize, pixelWidth, pixelHeight, pixelDepth, layerCount, faceCount,
//!        levelCount, supercompressionScheme (= 0)             9 x u32
//! 48     dfdByteOffset, dfdByteLength, kvdByteOffset, kvdByteLength   4 x u32
//! 64     sgdByteOffset, sgdByteLength (= 0, 0)                       2 x u64
//! 80     level index: levelCount x {byteOffset, byteLength, uncompressedByteLength} u64
//! ...    DFD: dfdTotalSize u32 + one basic descriptor block
//! ...    key/value data, sorted by key: {keyAndValueByteLength u32, key, NUL, value, pad to 4}
//! ...    mip levels from the smallest to the largest, each aligned to lcm(texel size, 4);
//!        inside a level: layer → face → z slice → row → texel, tightly packed
//! ```
//!
//! The reader validates every field against the file length and a [`Limits`] before it
//! allocates, and checks that the DFD describes the header's `vkFormat`.

use std::path::Path;

use crate::format::PixelFormat;
use crate::limits::{check_at_most, checked_product};
use crate::{Limits, TextureError};

/// The 12-byte KTX 2.0 file identifier.
pub const KTX2_IDENTIFIER: [u8; 12] = [
    0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A,
];
const HEADER_LEN: usize = 80;
const LEVEL_INDEX_ENTRY: usize = 24;

/// The standard key holding the texture's logical orientation (`"rd"`, `"rdi"`, ...).
pub const KEY_ORIENTATION: &str = "KTXorientation";
/// The standard key naming the program that wrote the file.
pub const KEY_WRITER: &str = "KTXwriter";
/// Our key: the JSON description of the array stored in a texture (see docs/formats.md).
pub const KEY_PRT_ARRAY: &str = "prt.array";

/// The shape of a texture: 1D/2D/3D extent, array layers and cubemap faces, as in the KTX2
/// header (`height == 0` for 1D, `depth == 0` for 1D/2D, `layers == 0` for a non-array).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Shape {
    /// Width in texels, at least 1.
    pub width: u32,
    /// Height in texels; 0 for a 1D texture.
    pub height: u32,
    /// Depth in texels; 0 unless the texture is 3D.
    pub depth: u32,
    /// Array layers; 0 for a non-array texture.
    pub layers: u32,
    /// Cubemap faces: 1, or 6 for a cubemap (faces +X, -X, +Y, -Y, +Z, -Z).
    pub faces: u32,
}

impl Shape {
    /// A 2D texture.
    pub fn d2(width: u32, height: u32) -> Shape {
        Shape {
            width,
            height,
            depth: 0,
            layers: 0,
            faces: 1,
        }
    }
    /// A 3D texture.
    pub fn d3(width: u32, height: u32, depth: u32) -> Shape {
        Shape {
            width,
            height,
            depth,
            layers: 0,
            faces: 1,
        }
    }
    /// A 2D array texture.
    pub fn d2_array(width: u32, height: u32, layers: u32) -> Shape {
        Shape {
            width,
            height,
            depth: 0,
            layers,
            faces: 1,
        }
    }
    /// A cubemap with square faces of `size` texels.
    pub fn cube(size: u32) -> Shape {
        Shape {
            width: size,
            height: size,
            depth: 0,
            layers: 0,
            faces: 6,
        }
    }

    /// Texels of mip level `level` over all layers and faces (with overflow checked).
    pub fn level_texels(&self, level: u32) -> Result<u64, TextureError> {
        let dim = |d: u32| u64::from((d >> level.min(31)).max(1));
        checked_product(
            "texel count",
            &[
                dim(self.width),
                dim(self.height),
                dim(self.depth),
                u64::from(self.layers.max(1)),
                u64::from(self.faces),
            ],
        )
    }

    /// Most mip levels a chain of this shape can have.
    pub fn max_levels(&self) -> u32 {
        let largest = self.width.max(self.height).max(self.depth).max(1);
        32 - largest.leading_zeros()
    }

    /// Checks the combinations the KTX2 specification allows (and that we support).
    pub fn validate(&self) -> Result<(), TextureError> {
        let bad = |why: &str| Err(TextureError::malformed("texture shape", why));
        if self.width == 0 {
            return bad("zero width");
        }
        if self.height == 0 && self.depth != 0 {
            return bad("1D texture with a depth");
        }
        match self.faces {
            1 => {}
            6 => {
                if self.width != self.height || self.depth != 0 {
                    return bad("cubemap faces must be square and 2D");
                }
            }
            n => return bad(&format!("face count {n} (must be 1 or 6)")),
        }
        if self.depth != 0 && self.layers != 0 {
            return Err(TextureError::Unsupported {
                what: "texture shape",
                why: "3D array textures".into(),
            });
        }
        Ok(())
    }

    fn default_orientation(&self) -> &'static str {
        if self.height == 0 {
            "r"
        } else if self.depth != 0 {
            "rdi"
        } else {
            "rd"
        }
    }
}

/// An uncompressed KTX2 texture held in memory: format, shape, mip levels and key/value data.
#[derive(Debug, Clone, PartialEq)]
pub struct Ktx2Texture {
    format: PixelFormat,
    shape: Shape,
    levels: Vec<Vec<u8>>,
    key_values: Vec<(String, Vec<u8>)>,
}

impl Ktx2Texture {
    /// A texture from raw texel bytes, `levels[0]` being the full-resolution level.
    ///
    /// Each level must hold exactly the texels of its mip size (layer → face → z → y → x) in
    /// `format`. The orientation key is set to the shape's natural value (`"r"`, `"rd"`,
    /// `"rdi"`) and `KTXwriter` to this crate.
    pub fn new(
        format: PixelFormat,
        shape: Shape,
        levels: Vec<Vec<u8>>,
    ) -> Result<Self, TextureError> {
        shape.validate()?;
        if levels.is_empty() || levels.len() > shape.max_levels() as usize {
            return Err(TextureError::invalid(
                "mip levels",
                format!(
                    "{} levels for a chain of at most {}",
                    levels.len(),
                    shape.max_levels()
                ),
            ));
        }
        for (i, level) in levels.iter().enumerate() {
            let expected = level_bytes(format, &shape, i as u32)?;
            if level.len() as u64 != expected {
                return Err(TextureError::LengthMismatch {
                    what: "mip level bytes",
                    expected: expected as usize,
                    got: level.len(),
                });
            }
        }
        let mut texture = Ktx2Texture {
            format,
            shape,
            levels,
            key_values: Vec::new(),
        };
        texture.set_default_keys();
        Ok(texture)
    }

    /// The orientation key (the shape's natural value) and `KTXwriter` (this crate).
    fn set_default_keys(&mut self) {
        self.set_key(
            KEY_ORIENTATION,
            nul_terminated(self.shape.default_orientation()),
        );
        self.set_key(
            KEY_WRITER,
            nul_terminated(concat!("prt-texture ", env!("CARGO_PKG_VERSION"))),
        );
    }

    /// A texture from `f32` values per level (channel-interleaved, `format.channels()` per
    /// texel), encoded with [`PixelFormat::encode`].
    pub fn from_f32(
        format: PixelFormat,
        shape: Shape,
        levels: &[Vec<f32>],
    ) -> Result<Self, TextureError> {
        let bytes = levels
            .iter()
            .map(|l| format.encode(l))
            .collect::<Result<Vec<_>, _>>()?;
        Ktx2Texture::new(format, shape, bytes)
    }

    /// The pixel format.
    pub fn format(&self) -> PixelFormat {
        self.format
    }

    /// The shape of level 0.
    pub fn shape(&self) -> Shape {
        self.shape
    }

    /// Raw bytes of every mip level, level 0 first.
    pub fn levels(&self) -> &[Vec<u8>] {
        &self.levels
    }

    /// Level `level` decoded to `f32` (channel-interleaved).
    pub fn level_f32(&self, level: usize) -> Result<Vec<f32>, TextureError> {
        let bytes = self.levels.get(level).ok_or_else(|| {
            TextureError::invalid("mip level", format!("{level} of {}", self.levels.len()))
        })?;
        self.format.decode(bytes)
    }

    /// Key/value pairs, sorted by key.
    pub fn key_values(&self) -> &[(String, Vec<u8>)] {
        &self.key_values
    }

    /// The value stored under `key`, if any.
    pub fn key(&self, key: &str) -> Option<&[u8]> {
        self.key_values
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_slice())
    }

    /// Sets (or replaces) a key/value pair, keeping keys sorted as the specification requires.
    ///
    /// Keys must be non-empty, contain no NUL and not start with a byte-order mark; keys
    /// starting with `KTX`/`ktx` are reserved for the standard ones (the writer does not
    /// police that, readers accept anything well-formed).
    pub fn set_key(&mut self, key: &str, value: Vec<u8>) {
        match self
            .key_values
            .binary_search_by(|(k, _)| k.as_bytes().cmp(key.as_bytes()))
        {
            Ok(i) => self.key_values[i].1 = value,
            Err(i) => self.key_values.insert(i, (key.to_owned(), value)),
        }
    }

    /// Serialises the texture as a KTX2 file.
    pub fn to_bytes(&self) -> Result<Vec<u8>, TextureError> {
        let lengths: Vec<u64> = self.levels.iter().map(|l| l.len() as u64).collect();
        let (mut out, offsets) = self.header(&lengths)?;
        for (level, &offset) in self.levels.iter().zip(&offsets).rev() {
            out.resize(offset as usize, 0);
            out.extend_from_slice(level);
        }
        Ok(out)
    }

    /// The bytes before the texels of the one-level texture [`Ktx2Texture::new`] makes of
    /// `format` and `shape` with `keys` set as [`Ktx2Texture::set_key`] sets them, and the
    /// level's length: the level's bytes written after them make the file
    /// [`Ktx2Texture::to_bytes`] writes. For a level too large to hold in memory.
    pub fn level_prefix(
        format: PixelFormat,
        shape: Shape,
        keys: Vec<(&str, Vec<u8>)>,
    ) -> Result<(Vec<u8>, u64), TextureError> {
        shape.validate()?;
        let length = level_bytes(format, &shape, 0)?;
        let mut texture = Ktx2Texture {
            format,
            shape,
            levels: Vec::new(),
            key_values: Vec::new(),
        };
        texture.set_default_keys();
        for (key, value) in keys {
            texture.set_key(key, value);
        }
        let (mut out, offsets) = texture.header(&[length])?;
        out.resize(offsets[0] as usize, 0);
        Ok((out, length))
    }

    /// The file's bytes before the first level's texels, and each level's offset, for levels of
    /// `lengths` bytes.
    fn header(&self, lengths: &[u64]) -> Result<(Vec<u8>, Vec<u64>), TextureError> {
        let level_count = lengths.len();
        let dfd = self.format.dfd_bytes();
        let mut kvd = Vec::new();
        for (key, value) in &self.key_values {
            if key.is_empty() || key.as_bytes().contains(&0) {
                return Err(TextureError::invalid(
                    "key",
                    format!("{key:?} (empty or containing NUL)"),
                ));
            }
            let len = u32::try_from(key.len() + 1 + value.len())
                .map_err(|_| TextureError::invalid("key/value", "longer than 4 GiB"))?;
            kvd.extend_from_slice(&len.to_le_bytes());
            kvd.extend_from_slice(key.as_bytes());
            kvd.push(0);
            kvd.extend_from_slice(value);
            pad_to(&mut kvd, 4);
        }
        let dfd_offset = HEADER_LEN + LEVEL_INDEX_ENTRY * level_count;
        let kvd_offset = dfd_offset + dfd.len();
        let mut out = Vec::with_capacity(kvd_offset + kvd.len() + 16);
        out.extend_from_slice(&KTX2_IDENTIFIER);
        let s = &self.shape;
        for v in [
            self.format.vk_format(),
            self.format.type_size(),
            s.width,
            s.height,
            s.depth,
            s.layers,
            s.faces,
            level_count as u32,
            0, // supercompression: none
            dfd_offset as u32,
            dfd.len() as u32,
            if kvd.is_empty() { 0 } else { kvd_offset as u32 },
            kvd.len() as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&[0u8; 16]); // no supercompression global data
        out.resize(dfd_offset, 0); // level index, filled below
        out.extend_from_slice(&dfd);
        out.extend_from_slice(&kvd);
        // Levels are stored smallest first, each aligned.
        let align = lcm(self.format.bytes_per_texel(), 4) as u64;
        let mut offsets = vec![0u64; level_count];
        let mut end = out.len() as u64;
        for (i, &len) in lengths.iter().enumerate().rev() {
            offsets[i] = end.next_multiple_of(align);
            end = offsets[i] + len;
        }
        for (i, (&offset, &len)) in offsets.iter().zip(lengths).enumerate() {
            let at = HEADER_LEN + LEVEL_INDEX_ENTRY * i;
            out[at..at + 8].copy_from_slice(&offset.to_le_bytes());
            out[at + 8..at + 16].copy_from_slice(&len.to_le_bytes());
            out[at + 16..at + 24].copy_from_slice(&len.to_le_bytes());
        }
        Ok((out, offsets))
    }

    /// Writes the texture to `path` atomically (temporary file, then rename).
    pub fn write_file(&self, path: &Path) -> Result<(), TextureError> {
        crate::write_atomic(path, &self.to_bytes()?)
    }

    /// Parses a KTX2 file held in memory, checking everything against `limits`.
    pub fn from_bytes(bytes: &[u8], limits: &Limits) -> Result<Self, TextureError> {
        parse(bytes, limits)
    }

    /// Reads and parses a KTX2 file (refusing files larger than `limits.max_bytes` plus
    /// headers before reading them).
    pub fn read_file(path: &Path, limits: &Limits) -> Result<Self, TextureError> {
        let bytes = crate::atomic::read_limited(path, limits.max_bytes.saturating_add(1 << 20))?;
        parse(&bytes, limits)
    }
}

/// Bytes of mip level `level` of a texture of `shape` in `format`.
pub fn level_bytes(format: PixelFormat, shape: &Shape, level: u32) -> Result<u64, TextureError> {
    checked_product(
        "level bytes",
        &[shape.level_texels(level)?, format.bytes_per_texel() as u64],
    )
}

fn nul_terminated(s: &str) -> Vec<u8> {
    let mut v = s.as_bytes().to_vec();
    v.push(0);
    v
}

fn pad_to(buf: &mut Vec<u8>, align: usize) {
    buf.resize(buf.len().next_multiple_of(align), 0);
}

fn lcm(a: usize, b: usize) -> usize {
    let gcd = |mut x: usize, mut y: usize| {
        while y != 0 {
            (x, y) = (y, x % y);
        }
        x
    };
    a / gcd(a, b) * b
}

/// A little-endian cursor over untrusted bytes; every read is bounds-checked.
struct Fields<'a> {
    bytes: &'a [u8],
}

impl Fields<'_> {
    fn u32_at(&self, what: &'static str, at: usize) -> Result<u32, TextureError> {
        let b = self.slice(what, at as u64, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64_at(&self, what: &'static str, at: usize) -> Result<u64, TextureError> {
        let b = self.slice(what, at as u64, 8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
    fn slice(&self, what: &'static str, offset: u64, len: u64) -> Result<&[u8], TextureError> {
        let available = self.bytes.len() as u64;
        let end =
            offset
                .checked_add(len)
                .filter(|&e| e <= available)
                .ok_or(TextureError::Truncated {
                    what,
                    needed: offset.saturating_add(len),
                    available,
                })?;
        // end <= len() fits in usize.
        Ok(&self.bytes[offset as usize..end as usize])
    }
}

fn parse(bytes: &[u8], limits: &Limits) -> Result<Ktx2Texture, TextureError> {
    let f = Fields { bytes };
    let header = f.slice("KTX2 header", 0, HEADER_LEN as u64)?;
    if header[..12] != KTX2_IDENTIFIER {
        return Err(TextureError::malformed(
            "KTX2 identifier",
            "not a KTX 2.0 file",
        ));
    }
    let word = |i: usize| f.u32_at("KTX2 header", 12 + 4 * i);
    let vk_format = word(0)?;
    let format =
        PixelFormat::from_vk_format(vk_format).ok_or_else(|| TextureError::Unsupported {
            what: "vkFormat",
            why: format!("{vk_format}"),
        })?;
    if word(1)? != format.type_size() {
        return Err(TextureError::malformed(
            "typeSize",
            format!(
                "{} for {format:?} (expected {})",
                word(1)?,
                format.type_size()
            ),
        ));
    }
    let shape = Shape {
        width: word(2)?,
        height: word(3)?,
        depth: word(4)?,
        layers: word(5)?,
        faces: word(6)?,
    };
    for (what, v) in [
        ("pixelWidth", shape.width),
        ("pixelHeight", shape.height),
        ("pixelDepth", shape.depth),
    ] {
        limits.check_dimension(what, u64::from(v))?;
    }
    check_at_most(
        "layerCount",
        u64::from(shape.layers),
        u64::from(limits.max_layers),
    )?;
    shape.validate()?;
    // levelCount 0 asks the loader to generate mips; one level is stored.
    let level_count = word(7)?.max(1);
    check_at_most(
        "levelCount",
        u64::from(level_count),
        u64::from(limits.max_levels),
    )?;
    check_at_most(
        "levelCount",
        u64::from(level_count),
        u64::from(shape.max_levels()),
    )?;
    let scheme = word(8)?;
    if scheme != 0 {
        return Err(TextureError::Unsupported {
            what: "supercompressionScheme",
            why: format!("{scheme}"),
        });
    }
    let (dfd_offset, dfd_len) = (word(9)?, word(10)?);
    let (kvd_offset, kvd_len) = (word(11)?, word(12)?);

    check_dfd(
        format,
        f.slice("DFD", u64::from(dfd_offset), u64::from(dfd_len))?,
    )?;
    let key_values =
        parse_kvd(f.slice("key/value data", u64::from(kvd_offset), u64::from(kvd_len))?)?;

    let mut total = 0u64;
    let mut sizes = Vec::with_capacity(level_count as usize);
    for level in 0..level_count {
        let size = level_bytes(format, &shape, level)?;
        total = total.saturating_add(size);
        limits.check_bytes("decoded texel bytes", total)?;
        sizes.push(size);
    }
    let mut levels = Vec::with_capacity(level_count as usize);
    for (level, &size) in sizes.iter().enumerate() {
        let at = HEADER_LEN + LEVEL_INDEX_ENTRY * level;
        let offset = f.u64_at("level index", at)?;
        let len = f.u64_at("level index", at + 8)?;
        let uncompressed = f.u64_at("level index", at + 16)?;
        if len != size || uncompressed != size {
            return Err(TextureError::malformed(
                "level index",
                format!(
                    "level {level} announces {len}/{uncompressed} bytes, its shape needs {size}"
                ),
            ));
        }
        levels.push(f.slice("mip level data", offset, len)?.to_vec());
    }
    Ok(Ktx2Texture {
        format,
        shape,
        levels,
        key_values,
    })
}

/// Checks that a DFD (with its `dfdTotalSize` word) is one basic block describing `format`.
fn check_dfd(format: PixelFormat, dfd: &[u8]) -> Result<(), TextureError> {
    let bad = |why: String| Err(TextureError::malformed("data format descriptor", why));
    let f = Fields { bytes: dfd };
    let total = f.u32_at("DFD", 0)?;
    if total as usize != dfd.len() {
        return bad(format!(
            "dfdTotalSize {total} but dfdByteLength {}",
            dfd.len()
        ));
    }
    let head = f.u32_at("DFD block header", 4)?;
    let version_and_size = f.u32_at("DFD block header", 8)?;
    let block_size = (version_and_size >> 16) as usize;
    if head != 0 {
        return bad(format!(
            "descriptor vendor/type word {head:#x} (expected the Khronos basic block)"
        ));
    }
    if block_size != dfd.len() - 4 {
        return bad(format!(
            "block size {block_size} in a DFD of {} bytes",
            dfd.len()
        ));
    }
    let expected = format.dfd_samples();
    if block_size != 24 + 16 * expected.len() {
        return bad(format!(
            "{} bytes of samples for {format:?}",
            block_size.saturating_sub(24)
        ));
    }
    let block = f.slice("DFD block", 12, 16)?;
    if block[4..8] != [0, 0, 0, 0] {
        return bad("texel block dimensions other than 1x1x1x1".into());
    }
    if block[8] as usize != format.bytes_per_texel() || block[9..16].iter().any(|&b| b != 0) {
        return bad(format!("bytesPlane0 {} for {format:?}", block[8]));
    }
    for (i, s) in expected.iter().enumerate() {
        let at = 28 + 16 * i;
        let word = f.u32_at("DFD sample", at)?;
        let (offset, length, channel) = (word & 0xffff, (word >> 16) & 0xff, word >> 24);
        if offset != u32::from(s.bit_offset)
            || length + 1 != u32::from(s.bit_length)
            || channel != u32::from(s.channel | (s.qualifiers << 4))
        {
            return bad(format!(
                "sample {i} (offset {offset}, length {}, channel {channel:#x}) does not describe {format:?}",
                length + 1
            ));
        }
    }
    Ok(())
}

fn parse_kvd(kvd: &[u8]) -> Result<Vec<(String, Vec<u8>)>, TextureError> {
    let bad = |why: String| Err(TextureError::malformed("key/value data", why));
    let f = Fields { bytes: kvd };
    let mut out: Vec<(String, Vec<u8>)> = Vec::new();
    let mut at = 0usize;
    while at < kvd.len() {
        let len = f.u32_at("key/value length", at)? as u64;
        let entry = f.slice("key/value entry", at as u64 + 4, len)?;
        let Some(nul) = entry.iter().position(|&b| b == 0) else {
            return bad(format!("entry at {at} has no NUL after its key"));
        };
        let Ok(key) = std::str::from_utf8(&entry[..nul]) else {
            return bad(format!("entry at {at} has a key that is not UTF-8"));
        };
        if key.is_empty() {
            return bad(format!("entry at {at} has an empty key"));
        }
        if out.iter().any(|(k, _)| k == key) {
            return bad(format!("duplicate key {key:?}"));
        }
        out.push((key.to_owned(), entry[nul + 1..].to_vec()));
        // entry.len() == len, so this does not overflow: at + 4 + len <= kvd.len().
        at = (at + 4 + entry.len()).next_multiple_of(4);
    }
    out.sort_by(|a, b| a.0.as_bytes().cmp(b.0.as_bytes()));
    Ok(out)
}

/// A mip chain of `levels` levels (level 0 included) by 2×2(×2) box filtering, for `f32`
/// texels with `channels` values each, laid out as in a KTX2 level (layer → face → z → y → x).
///
/// Each texel of level i+1 averages the texels `2x, 2x+1` (and y, z alike) of level i (only
/// `x` along an axis of size 1; the last texel of an odd size is dropped, as a plain 2× box
/// filter does), so constant images stay constant and, for power-of-two sizes, every level has
/// the mean of level 0. Sums are accumulated in f64.
/// Layers and cubemap faces are filtered independently (no filtering across faces).
pub fn box_mip_chain(
    shape: Shape,
    channels: usize,
    level0: &[f32],
    levels: u32,
) -> Result<Vec<Vec<f32>>, TextureError> {
    shape.validate()?;
    if levels == 0 || levels > shape.max_levels() {
        return Err(TextureError::invalid(
            "mip levels",
            format!("{levels} for a chain of at most {}", shape.max_levels()),
        ));
    }
    let expected = shape.level_texels(0)? as usize * channels;
    if level0.len() != expected || channels == 0 {
        return Err(TextureError::LengthMismatch {
            what: "mip level 0 values",
            expected,
            got: level0.len(),
        });
    }
    TextureError::check_finite("mip level 0 values", level0)?;
    let images = (shape.layers.max(1) * shape.faces) as usize;
    let dims = |l: u32| [shape.width, shape.height, shape.depth].map(|d| (d >> l).max(1) as usize);
    let mut chain = vec![level0.to_vec()];
    for l in 1..levels {
        let [sw, sh, sd] = dims(l - 1);
        let [w, h, d] = dims(l);
        let src = &chain[(l - 1) as usize];
        let mut dst = vec![0f32; images * w * h * d * channels];
        let mut acc = vec![0f64; channels];
        for image in 0..images {
            for z in 0..d {
                for y in 0..h {
                    for x in 0..w {
                        acc.iter_mut().for_each(|a| *a = 0.0);
                        let (zs, ys, xs) =
                            ([2 * z, 2 * z + 1], [2 * y, 2 * y + 1], [2 * x, 2 * x + 1]);
                        let (nz, ny, nx) = (
                            if sd > 1 { 2 } else { 1 },
                            if sh > 1 { 2 } else { 1 },
                            if sw > 1 { 2 } else { 1 },
                        );
                        for &zz in &zs[..nz] {
                            for &yy in &ys[..ny] {
                                for &xx in &xs[..nx] {
                                    let t = ((image * sd + zz) * sh + yy) * sw + xx;
                                    for (a, &v) in
                                        acc.iter_mut().zip(&src[t * channels..(t + 1) * channels])
                                    {
                                        *a += f64::from(v);
                                    }
                                }
                            }
                        }
                        let n = (nz * ny * nx) as f64;
                        let t = ((image * d + z) * h + y) * w + x;
                        for (o, a) in dst[t * channels..(t + 1) * channels].iter_mut().zip(&acc) {
                            *o = (a / n) as f32;
                        }
                    }
                }
            }
        }
        chain.push(dst);
    }
    Ok(chain)
}
