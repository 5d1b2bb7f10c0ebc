//! The prt container: a versioned JSON manifest plus one KTX2 texture per named array.
//!
//! The container knows no basis and no solver. It stores named, typed arrays that live on 3D
//! grids of nodes (`dims`, `channels` values per node), each quantised with its own
//! [`Encoding`] and per-channel [`ChannelRange`]s, plus free-form attributes and kernel
//! descriptions. A Moving Basis Decomposition model (Silvennoinen & Sloan, "Moving Basis
//! Decomposition for Precomputed Light Transport", EGSR 2021) maps onto it as
//!
//! | array | dims | channels | layout |
//! |---|---|---|---|
//! | [`MBD_COEFFICIENTS`] | coefficient-kernel nodes | L (rank) | [`ArrayLayout::Volume`]: L channels packed in RGBA 3D textures |
//! | [`MBD_BASIS`] | basis-kernel nodes | D x L (basis matrix per node, row-major) | [`ArrayLayout::Atlas`] (filterable) or [`ArrayLayout::Rows`] |
//!
//! (the coefficients may instead be in [`ArrayLayout::Bricks`]: only the bricks holding live
//! nodes, in a brick atlas, with an indirection grid; [`Container::bricks`] says which nodes)
//!
//! with two [`KernelDescription`]s (kind, node counts, domain) under the same names. The byte
//! layout of the manifest and of the textures is in docs/formats.md.
//!
//! **Filterable layouts.** [`ArrayLayout::Volume`] and [`ArrayLayout::Atlas`] put each group of
//! four channels in its own tile, a 3D block of the array's node dims, with node `i` at texel
//! `i` of its tile. A hat grid whose node `i` maps to texel centre `i` is then evaluated by
//! hardware trilinear filtering, provided the sampling coordinate is clamped to the tile's
//! outer texel centres (so no filter footprint reaches a neighbouring tile); see [`atlas_tiles`]
//! and [`ArrayEntry::tile_of`].
//!
//! Writing quantises, writes every texture atomically and the manifest last (so a reader never
//! sees a manifest naming missing files), and reports the bytes actually written.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};

pub use crate::bricks::{
    BrickRequest, Bricks, DEFAULT_BRICK_SIZE, LiveBricks, MAX_ATLAS_BRICKS, MAX_BRICK_SIZE,
    brick_atlas, brick_grid, live_bricks,
};
use crate::bricks::{atlas_texels, brick_of, slot_coordinate};
use crate::ktx2::{KEY_PRT_ARRAY, Ktx2Texture, Shape};
use crate::limits::{check_at_most, checked_product};
use crate::quant::{ChannelRange, Encoding, Quantized, dequantize, quantize};
use crate::{Limits, PixelFormat, TextureError};

/// Value of [`Manifest::format`].
pub const CONTAINER_FORMAT: &str = "prt-container";
/// The manifest version this crate writes; it reads every version from 1 up to this one
/// (version 2 stopped storing identity ranges for the float encodings, version 3 added
/// [`ArrayLayout::Atlas`], version 4 single-channel formats, version 5 [`ArrayLayout::Bricks`]).
pub const CONTAINER_VERSION: u32 = 5;
/// File name of the manifest inside a container folder.
pub const MANIFEST_FILE: &str = "manifest.json";
/// Name of the MBD coefficient grid array and its kernel.
pub const MBD_COEFFICIENTS: &str = "coefficients";
/// Name of the MBD basis grid array and its kernel.
pub const MBD_BASIS: &str = "basis";
/// Largest manifest we read, in bytes.
pub const MAX_MANIFEST_BYTES: usize = 1 << 20;
/// Largest texture dimension the `Volume` layout produces (Vulkan's guaranteed 3D minimum).
pub const MAX_VOLUME_DEPTH: u64 = 2048;

/// A dense array on a 3D grid: `channels` values per node, nodes x-fastest then y then z.
#[derive(Debug, Clone, PartialEq)]
pub struct GridArray {
    /// Node counts along x, y, z (each at least 1).
    pub dims: [u32; 3],
    /// Values per node (at least 1).
    pub channels: usize,
    /// `dims[0]·dims[1]·dims[2]·channels` values, node-major.
    pub data: Vec<f32>,
}

impl GridArray {
    /// An array from its values; checks the length and that every value is finite.
    pub fn new(dims: [u32; 3], channels: usize, data: Vec<f32>) -> Result<Self, TextureError> {
        let array = GridArray {
            dims,
            channels,
            data,
        };
        array.check()?;
        Ok(array)
    }

    /// Number of nodes.
    pub fn nodes(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    fn check(&self) -> Result<(), TextureError> {
        if self.dims.contains(&0) || self.channels == 0 {
            return Err(TextureError::invalid(
                "grid array",
                "zero dimension or zero channels",
            ));
        }
        let expected = checked_product(
            "grid array values",
            &[
                self.dims[0].into(),
                self.dims[1].into(),
                self.dims[2].into(),
                self.channels as u64,
            ],
        )?;
        if self.data.len() as u64 != expected {
            return Err(TextureError::LengthMismatch {
                what: "grid array values",
                expected: expected as usize,
                got: self.data.len(),
            });
        }
        TextureError::check_finite("grid array values", &self.data)
    }
}

/// How the channel groups of an array are laid out in its texture.
///
/// A *group* is four consecutive channels (three for RGB9E5), one texel per node; the last
/// group is padded with zeros.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArrayLayout {
    /// A 3D texture of `(dims[0], dims[1], dims[2]·groups)`: channel group `g` occupies slices
    /// `g·dims[2] .. (g+1)·dims[2]`, so each group is a hardware-filterable volume (an atlas
    /// with tiles `[1, 1, groups]`).
    Volume,
    /// A 3D texture of tiles: group `g` is the block of `dims` texels at tile
    /// [`ArrayEntry::tile_of`]`(g)` of a `tiles[0] × tiles[1] × tiles[2]` arrangement
    /// ([`ArrayEntry::tiles`], chosen by [`atlas_tiles`] when writing). For arrays with many
    /// groups (an MBD basis has 81·L), where stacking them along z would exceed texture limits.
    Atlas,
    /// A 2D texture of `(groups, nodes)`: row `n` holds node `n`'s channel groups (not
    /// filterable; for tools).
    Rows,
    /// Sparse and filterable: the node grid cut into bricks of `B` cells ([`Bricks`]); only the
    /// bricks holding a live node are stored, each as `(B+1)³` texels (a one-node apron on the
    /// high side) in a 3D brick atlas, one atlas per channel group stacked along z; an
    /// RGBA8 indirection texture of one texel per brick gives its atlas brick coordinate
    /// (alpha 1) or says it is empty (all 0). Nodes of empty bricks read back as 0. For
    /// coefficient volumes of scenes with much empty or solid space (container version 5).
    Bricks,
}

/// The tile arrangement [`Container::encode`] gives an [`ArrayLayout::Atlas`] of `groups` tiles
/// of `dims` texels: close to a cube in texels (so no side grows much beyond the others),
/// filled x first, then y, then z, with no empty layer of tiles along z.
pub fn atlas_tiles(dims: [u32; 3], groups: usize) -> [u32; 3] {
    let groups = groups.max(1) as f64;
    let texels: f64 = dims.iter().map(|&d| f64::from(d)).product();
    let side = (groups * texels).cbrt();
    let fit = |d: u32, most: f64| (side / f64::from(d)).round().clamp(1.0, most.max(1.0));
    let tx = fit(dims[0], groups);
    let ty = fit(dims[1], (groups / tx).ceil());
    let tz = (groups / (tx * ty)).ceil();
    [tx as u32, ty as u32, tz as u32]
}

/// A spatial kernel family, described for a reader that rebuilds it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KernelDescription {
    /// Kernel kind, e.g. `"hat"` (trilinear hat grid) or `"shepard"`.
    pub kind: String,
    /// Node counts along x, y, z.
    pub nodes: [u32; 3],
    /// Lower corner of the domain (metres).
    pub domain_min: [f32; 3],
    /// Upper corner of the domain (metres).
    pub domain_max: [f32; 3],
}

/// One array's entry in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArrayEntry {
    /// Unique array name: ASCII letters, digits, `_`, `-`, `.`; at most 64 bytes.
    pub name: String,
    /// The KTX2 file holding it (`<name>.ktx2`, in the container folder).
    pub file: String,
    /// Node counts along x, y, z.
    pub dims: [u32; 3],
    /// Values per node.
    pub channels: usize,
    /// Texel encoding.
    pub encoding: Encoding,
    /// Texture layout of the channel groups.
    pub layout: ArrayLayout,
    /// Tiles along x, y, z of an [`ArrayLayout::Atlas`] (absent for the other layouts).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tiles: Option<[u32; 3]>,
    /// The bricks of an [`ArrayLayout::Bricks`] array (absent for the other layouts).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bricks: Option<Bricks>,
    /// Per-channel decode map of the normalised encodings, `value = bias + scale · texel`.
    /// Empty for the float encodings and RGB9E5, which decode directly (container version 1
    /// wrote identity maps there; they are still accepted). Use [`ArrayEntry::range`] to read it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ranges: Vec<ChannelRange>,
    /// `true` when a one-channel array is stored in a one-channel texture format (R32F, R16F,
    /// R8 for the f32, f16 and unorm8 encodings) instead of the encoding's RGBA format;
    /// containers before version 4 never are.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub single_channel: bool,
    /// Size of the KTX2 file in bytes.
    pub bytes: u64,
}

/// The one-channel texture format of `encoding`, where it has one.
fn single_channel_format(encoding: Encoding) -> Option<PixelFormat> {
    match encoding {
        Encoding::F32 => Some(PixelFormat::R32Sfloat),
        Encoding::F16 => Some(PixelFormat::R16Sfloat),
        Encoding::Unorm8 => Some(PixelFormat::R8Unorm),
        _ => None,
    }
}

impl ArrayEntry {
    /// The texture format of the array's file: the encoding's RGBA format, or its one-channel
    /// format for a [`single_channel`](ArrayEntry::single_channel) array.
    pub fn texture_format(&self) -> PixelFormat {
        match single_channel_format(self.encoding) {
            Some(format) if self.single_channel => format,
            _ => self.encoding.rgba_format(),
        }
    }

    /// Channels per texel of [`ArrayEntry::texture_format`] (4, 3 for RGB9E5, 1 for a
    /// single-channel array).
    pub fn group_size(&self) -> usize {
        self.texture_format().channels()
    }

    /// The decode map of `channel`: its stored range for the normalised encodings, the identity
    /// for encodings that store none.
    pub fn range(&self, channel: usize) -> ChannelRange {
        self.ranges
            .get(channel)
            .copied()
            .unwrap_or(ChannelRange::IDENTITY)
    }

    /// Number of texels per node.
    pub fn groups(&self) -> usize {
        self.channels.div_ceil(self.group_size())
    }

    /// The tile arrangement of a filterable layout (`[1, 1, groups]` for
    /// [`ArrayLayout::Volume`]); `None` for [`ArrayLayout::Rows`] or an atlas without tiles.
    pub fn tile_grid(&self) -> Option<[u32; 3]> {
        match self.layout {
            ArrayLayout::Volume => Some([1, 1, u32::try_from(self.groups()).ok()?]),
            ArrayLayout::Atlas => self.tiles,
            ArrayLayout::Rows | ArrayLayout::Bricks => None,
        }
    }

    /// The tile `(tx, ty, tz)` holding channel group `g` in a filterable layout: group `g` is
    /// tile `g mod tiles[0]`, `(g / tiles[0]) mod tiles[1]`, `g / (tiles[0]·tiles[1])`; its texel
    /// for node `(i, j, k)` is `(tx·dims[0] + i, ty·dims[1] + j, tz·dims[2] + k)`.
    pub fn tile_of(&self, g: usize) -> Option<[u32; 3]> {
        let [tx, ty, _] = self.tile_grid()?.map(|t| t as usize);
        if g >= self.groups() {
            return None;
        }
        Some([g % tx, g / tx % ty, g / (tx * ty)].map(|t| t as u32))
    }

    fn texture_shape(&self) -> Result<Shape, TextureError> {
        let groups = self.groups() as u64;
        let nodes = checked_product("array nodes", &self.dims.map(u64::from))?;
        let [x, y, z] = self.dims.map(u64::from);
        let (w, h, d) = match (self.layout, self.tile_grid()) {
            (ArrayLayout::Rows, _) => (groups, nodes, 0),
            (ArrayLayout::Bricks, _) => {
                let bricks = self.bricks.as_ref().ok_or_else(|| {
                    TextureError::malformed(
                        "manifest",
                        format!("array {:?} has no bricks", self.name),
                    )
                })?;
                let [w, h, d] = atlas_texels(bricks, self.groups())?;
                (w, h, d)
            }
            (_, Some([tx, ty, tz])) => (x * u64::from(tx), y * u64::from(ty), z * u64::from(tz)),
            (_, None) => {
                return Err(TextureError::malformed(
                    "manifest",
                    format!("array {:?} has no tiles", self.name),
                ));
            }
        };
        let fits = |v: u64| {
            u32::try_from(v).map_err(|_| TextureError::TooLarge {
                what: "texture dimension",
                value: v,
                limit: u64::from(u32::MAX),
            })
        };
        Ok(if d == 0 {
            Shape::d2(fits(w)?, fits(h)?)
        } else {
            Shape::d3(fits(w)?, fits(h)?, fits(d)?)
        })
    }

    fn validate(&self, limits: &Limits) -> Result<(), TextureError> {
        let name_ok = !self.name.is_empty()
            && self.name.len() <= 64
            && self
                .name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"_-.".contains(&b))
            && !self.name.starts_with('.');
        if !name_ok {
            return Err(TextureError::malformed(
                "manifest",
                format!("array name {:?}", self.name),
            ));
        }
        if self.file != format!("{}.ktx2", self.name) {
            return Err(TextureError::malformed(
                "manifest",
                format!("file {:?} for array {:?}", self.file, self.name),
            ));
        }
        if self.dims.contains(&0) || self.channels == 0 {
            return Err(TextureError::malformed(
                "manifest",
                format!("array {:?} is empty", self.name),
            ));
        }
        check_at_most("array channels", self.channels as u64, limits.max_bytes)?;
        if self.single_channel
            && (self.channels != 1 || single_channel_format(self.encoding).is_none())
        {
            return Err(TextureError::malformed(
                "manifest",
                format!(
                    "array {:?} is single-channel with {} channels in {:?}",
                    self.name, self.channels, self.encoding
                ),
            ));
        }
        // An atlas names its tiles (enough for every group, no empty layer of tiles along z);
        // the other layouts name none.
        let tiles_ok = match (self.layout, self.tiles) {
            (ArrayLayout::Atlas, Some(t)) => {
                // u128: the products of three u32 cannot overflow.
                let [tx, ty, tz] = t.map(u128::from);
                let layer = tx * ty;
                let groups = self.groups() as u128;
                !t.contains(&0) && layer * tz >= groups && layer * (tz - 1) < groups
            }
            (ArrayLayout::Atlas, None) => false,
            (_, tiles) => tiles.is_none(),
        };
        self.validate_bricks()?;
        if !tiles_ok {
            return Err(TextureError::malformed(
                "manifest",
                format!(
                    "array {:?}: tiles {:?} for a {:?} layout of {} groups",
                    self.name,
                    self.tiles,
                    self.layout,
                    self.groups()
                ),
            ));
        }
        // Normalised encodings need one range per channel; the others store none (or, as
        // version 1 wrote them, identity maps).
        let ranges_ok = if self.encoding.is_normalized() {
            self.ranges.len() == self.channels
        } else {
            self.ranges.is_empty()
                || (self.ranges.len() == self.channels
                    && self.ranges.iter().all(|r| *r == ChannelRange::IDENTITY))
        };
        if !ranges_ok {
            return Err(TextureError::malformed(
                "manifest",
                format!(
                    "array {:?}: {} ranges for {} channels",
                    self.name,
                    self.ranges.len(),
                    self.channels
                ),
            ));
        }
        if let Some(i) = self
            .ranges
            .iter()
            .position(|r| !r.scale.is_finite() || !r.bias.is_finite() || r.scale < 0.0)
        {
            return Err(TextureError::malformed(
                "manifest",
                format!("array {:?}: range {i}", self.name),
            ));
        }
        let shape = self.texture_shape()?;
        for v in [shape.width, shape.height, shape.depth] {
            limits.check_dimension("array texture dimension", u64::from(v))?;
        }
        if let Some(bricks) = &self.bricks {
            for v in bricks.grid {
                limits.check_dimension("indirection texture dimension", u64::from(v))?;
            }
            // A small atlas can stand for a huge grid: bound what decoding it allocates.
            let dims = self.dims.map(u64::from);
            let decoded = checked_product(
                "decoded brick array bytes",
                &[dims[0], dims[1], dims[2], (self.groups() * 4) as u64, 4],
            )?;
            check_at_most("decoded brick array bytes", decoded, limits.max_bytes)?;
        }
        Ok(())
    }

    /// A brick-layout array names consistent bricks; the other layouts name none.
    fn validate_bricks(&self) -> Result<(), TextureError> {
        let bricks = match (self.layout, &self.bricks) {
            (ArrayLayout::Bricks, Some(bricks)) => bricks,
            (ArrayLayout::Bricks, None) => {
                return Err(TextureError::malformed(
                    "manifest",
                    format!("array {:?} has the bricks layout but no bricks", self.name),
                ));
            }
            (_, None) => return Ok(()),
            (layout, Some(_)) => {
                return Err(TextureError::malformed(
                    "manifest",
                    format!("array {:?}: bricks for a {layout:?} layout", self.name),
                ));
            }
        };
        let bad = |why: String| {
            Err(TextureError::malformed(
                "manifest",
                format!("array {:?}: {why}", self.name),
            ))
        };
        if !(1..=MAX_BRICK_SIZE).contains(&bricks.size) {
            return bad(format!("brick size {}", bricks.size));
        }
        if bricks.grid != brick_grid(self.dims, bricks.size) {
            return bad(format!(
                "{:?} bricks of {} cells for {:?} nodes",
                bricks.grid, bricks.size, self.dims
            ));
        }
        // u128: the products of three u32 cannot overflow.
        let product = |v: [u32; 3]| v.map(u128::from).iter().product::<u128>();
        let live = u128::from(bricks.live);
        let atlas_ok = bricks
            .atlas
            .iter()
            .all(|&a| (1..=MAX_ATLAS_BRICKS).contains(&a))
            && product(bricks.atlas) >= live
            && live <= product(bricks.grid);
        if !atlas_ok {
            return bad(format!(
                "an atlas of {:?} bricks for {} live of {:?}",
                bricks.atlas, bricks.live, bricks.grid
            ));
        }
        if bricks.indirection != format!("{}.bricks.ktx2", self.name) {
            return bad(format!("indirection file {:?}", bricks.indirection));
        }
        Ok(())
    }
}

/// The container manifest (`manifest.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always [`CONTAINER_FORMAT`].
    pub format: String,
    /// Always [`CONTAINER_VERSION`] for files this crate writes.
    pub version: u32,
    /// Free-form metadata (e.g. `"dimension"`, `"rank"`, `"basis"` for MBD).
    #[serde(default)]
    pub attributes: BTreeMap<String, serde_json::Value>,
    /// Kernel families by name.
    #[serde(default)]
    pub kernels: BTreeMap<String, KernelDescription>,
    /// The arrays, in the order they were added.
    pub arrays: Vec<ArrayEntry>,
}

impl Manifest {
    /// Parses and validates a manifest (size, version, names, ranges, texture dimensions).
    pub fn from_json(bytes: &[u8], limits: &Limits) -> Result<Manifest, TextureError> {
        check_at_most(
            "manifest bytes",
            bytes.len() as u64,
            MAX_MANIFEST_BYTES as u64,
        )?;
        let manifest: Manifest =
            serde_json::from_slice(bytes).map_err(|e| TextureError::Json(e.to_string()))?;
        manifest.validate(limits)?;
        Ok(manifest)
    }

    /// Pretty-printed JSON of the manifest.
    pub fn to_json(&self) -> Result<Vec<u8>, TextureError> {
        serde_json::to_vec_pretty(self).map_err(|e| TextureError::Json(e.to_string()))
    }

    fn validate(&self, limits: &Limits) -> Result<(), TextureError> {
        if self.format != CONTAINER_FORMAT {
            return Err(TextureError::malformed(
                "manifest",
                format!("format {:?}", self.format),
            ));
        }
        if !(1..=CONTAINER_VERSION).contains(&self.version) {
            return Err(TextureError::Unsupported {
                what: "manifest version",
                why: format!("{} (this reader knows {CONTAINER_VERSION})", self.version),
            });
        }
        for (i, entry) in self.arrays.iter().enumerate() {
            entry.validate(limits)?;
            if self.arrays[..i].iter().any(|e| e.name == entry.name) {
                return Err(TextureError::malformed(
                    "manifest",
                    format!("duplicate array {:?}", entry.name),
                ));
            }
        }
        Ok(())
    }
}

/// What to store: arrays with their encodings, attributes and kernels.
#[derive(Debug, Clone, Default)]
pub struct Container {
    /// Free-form metadata copied into the manifest.
    pub attributes: BTreeMap<String, serde_json::Value>,
    /// Kernel families by name.
    pub kernels: BTreeMap<String, KernelDescription>,
    /// Named arrays with their encoding and layout, in order.
    pub arrays: Vec<(String, GridArray, Encoding, ArrayLayout)>,
    /// The brick size and live nodes of every [`ArrayLayout::Bricks`] array, by name.
    pub bricks: BTreeMap<String, BrickRequest>,
}

/// A file of a container: its name and bytes.
pub type EncodedFile = (String, Vec<u8>);

/// Sizes of what [`Container::write`] put on disk.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteReport {
    /// The manifest as written.
    pub manifest: Manifest,
    /// Bytes of `manifest.json`.
    pub manifest_bytes: u64,
    /// Bytes of all files (textures and manifest).
    pub total_bytes: u64,
}

impl WriteReport {
    /// Bytes actually written per voxel of a field of `voxels` voxels.
    pub fn bytes_per_voxel(&self, voxels: u64) -> f64 {
        self.total_bytes as f64 / voxels.max(1) as f64
    }
}

impl Container {
    /// Quantises every array and encodes the textures; returns the manifest (with file sizes)
    /// and `(file name, bytes)` of every texture.
    pub fn encode(&self) -> Result<(Manifest, Vec<EncodedFile>), TextureError> {
        let (entries, files) = self.encode_arrays()?;
        Ok((self.manifest(entries)?, files))
    }

    fn encode_arrays(&self) -> Result<(Vec<ArrayEntry>, Vec<EncodedFile>), TextureError> {
        let mut entries = Vec::with_capacity(self.arrays.len());
        let mut files = Vec::with_capacity(self.arrays.len());
        for (name, array, encoding, layout) in &self.arrays {
            array.check()?;
            let live = match (layout, self.bricks.get(name)) {
                (ArrayLayout::Bricks, Some(request)) => Some(LiveBricks::of_nodes(
                    array.dims,
                    request.size,
                    &request.live_nodes,
                )?),
                _ => None,
            };
            let mut entry = new_entry(
                name,
                array.dims,
                array.channels,
                *encoding,
                *layout,
                live.as_ref(),
            )?;
            let live = live.as_ref().map(LiveBricks::live);
            let (texture, ranges) = encode_array(&entry, array, live)?;
            entry.ranges = ranges;
            if let (Some(live), Some(bricks)) = (live, &entry.bricks) {
                let bytes = indirection_texture(bricks, live)?.to_bytes()?;
                if let Some(b) = entry.bricks.as_mut() {
                    b.indirection_bytes = bytes.len() as u64;
                }
                files.push((format!("{name}.bricks.ktx2"), bytes));
            }
            let mut texture = texture;
            texture.set_key(KEY_PRT_ARRAY, embedded_entry(&entry)?);
            let bytes = texture.to_bytes()?;
            entry.bytes = bytes.len() as u64;
            entry.validate(&UNBOUNDED)?;
            files.push((entry.file.clone(), bytes));
            entries.push(entry);
        }
        Ok((entries, files))
    }

    /// The manifest of `entries` with this container's attributes and kernels, validated.
    fn manifest(&self, entries: Vec<ArrayEntry>) -> Result<Manifest, TextureError> {
        let manifest = Manifest {
            format: CONTAINER_FORMAT.into(),
            version: CONTAINER_VERSION,
            attributes: self.attributes.clone(),
            kernels: self.kernels.clone(),
            arrays: entries,
        };
        manifest.validate(&UNBOUNDED)?;
        Ok(manifest)
    }

    /// Writes the container into `folder` (created if missing): textures first, manifest last,
    /// each atomically.
    pub fn write(&self, folder: &Path) -> Result<WriteReport, TextureError> {
        self.write_with_streamed(folder, Vec::new())
    }

    /// [`Container::write`] with arrays [`ArrayStream`] has already written into `folder`:
    /// `(i, entry)` puts `entry` at index `i` of the manifest's arrays (in increasing `i`), the
    /// container's own arrays filling the other places in order.
    pub fn write_with_streamed(
        &self,
        folder: &Path,
        streamed: Vec<(usize, ArrayEntry)>,
    ) -> Result<WriteReport, TextureError> {
        let (mut entries, files) = self.encode_arrays()?;
        let mut total = 0u64;
        for (i, entry) in streamed {
            if i > entries.len() || entries.iter().any(|e| e.name == entry.name) {
                return Err(TextureError::invalid(
                    "container",
                    format!("streamed array {:?} at index {i}", entry.name),
                ));
            }
            total += entry.bytes + entry.bricks.as_ref().map_or(0, |b| b.indirection_bytes);
            entries.insert(i, entry);
        }
        let manifest = self.manifest(entries)?;
        std::fs::create_dir_all(folder).map_err(|e| TextureError::io(folder, e))?;
        for (file, bytes) in &files {
            crate::write_atomic(&folder.join(file), bytes)?;
            total += bytes.len() as u64;
        }
        let json = manifest.to_json()?;
        crate::write_atomic(&folder.join(MANIFEST_FILE), &json)?;
        Ok(WriteReport {
            manifest_bytes: json.len() as u64,
            total_bytes: total + json.len() as u64,
            manifest,
        })
    }
}

/// Limits that check a manifest's consistency only (for what this crate writes).
const UNBOUNDED: Limits = Limits {
    max_dimension: u32::MAX,
    max_layers: u32::MAX,
    max_levels: 32,
    max_bytes: u64::MAX,
};

/// The manifest entry of an array (sizes and ranges still to fill in); `live`, which bricks are
/// live, for the bricks layout.
fn new_entry(
    name: &str,
    dims: [u32; 3],
    channels: usize,
    encoding: Encoding,
    layout: ArrayLayout,
    live: Option<&LiveBricks>,
) -> Result<ArrayEntry, TextureError> {
    let mut entry = ArrayEntry {
        name: name.to_string(),
        file: format!("{name}.ktx2"),
        dims,
        channels,
        encoding,
        layout,
        tiles: None,
        bricks: None,
        ranges: Vec::new(),
        single_channel: channels == 1 && single_channel_format(encoding).is_some(),
        bytes: 0,
    };
    if layout == ArrayLayout::Atlas {
        entry.tiles = Some(atlas_tiles(dims, entry.groups()));
    }
    match (layout, live) {
        (ArrayLayout::Bricks, Some(live)) => {
            if live.dims() != dims {
                return Err(TextureError::invalid(
                    "container",
                    format!(
                        "array {name:?} of {dims:?} nodes given the live bricks of {:?}",
                        live.dims()
                    ),
                ));
            }
            let count = live.count();
            entry.bricks = Some(Bricks {
                size: live.size(),
                grid: brick_grid(dims, live.size()),
                live: count,
                atlas: brick_atlas(count)?,
                indirection: format!("{name}.bricks.ktx2"),
                indirection_bytes: 0,
            });
        }
        (ArrayLayout::Bricks, None) => {
            return Err(TextureError::invalid(
                "container",
                format!("array {name:?} has the bricks layout but no brick request"),
            ));
        }
        _ => {}
    }
    Ok(entry)
}

/// The entry a texture embeds to name its manifest entry (a reader tells it from another
/// container's); the decode ranges stay in the manifest alone (they can be most of an entry).
fn embedded_entry(entry: &ArrayEntry) -> Result<Vec<u8>, TextureError> {
    let embedded = ArrayEntry {
        ranges: Vec::new(),
        ..entry.clone()
    };
    serde_json::to_vec(&embedded).map_err(|e| TextureError::Json(e.to_string()))
}

/// The atlas slot of an empty brick in [`ArrayStream`]'s table (the atlas has at most
/// `MAX_ATLAS_BRICKS³` = 2²⁴ slots).
const NO_SLOT: u32 = u32::MAX;

/// Bytes of texels and of their file offsets [`ArrayStream`] holds before writing them out
/// (sorted by offset): an offset (16 bytes) outweighs a small texel.
const STREAM_BUFFER_BYTES: usize = 16 << 20;

/// One array's texture written a block of nodes at a time, in memory bounded by the block, a
/// write buffer, the blocks written so far (their corners) and, in bricks, four bytes per brick,
/// for an array too large to hold: the file [`Container::write`] writes for the
/// same values, encoding and layout, given the channel ranges of the whole array up front
/// ([`crate::RangeFit`]; ignored by the encodings without ranges). The file is written under a
/// temporary name, its texels placed by offset, and renamed by [`ArrayStream::finish`] once
/// every node has been written exactly once; then [`Container::write_with_streamed`] writes
/// the rest of the container and the manifest.
#[derive(Debug)]
pub struct ArrayStream {
    entry: ArrayEntry,
    /// One per quantised channel (the array's channels padded to whole texels).
    ranges: Vec<ChannelRange>,
    /// The texture under its temporary name (removed if the stream is dropped unfinished).
    out: crate::atomic::AtomicFile,
    /// Where the level's texels begin in the file.
    level_offset: u64,
    placement: Placement,
    /// The blocks written (corner and size): a new block must overlap none.
    written: Vec<([u32; 3], [u32; 3])>,
    /// Their nodes.
    written_nodes: u64,
    /// Texels waiting to be written: (file offset, index into `buffer` in texels).
    pending: Vec<(u64, usize)>,
    buffer: Vec<u8>,
}

/// Where a node's texels go in the level.
#[derive(Debug)]
enum Placement {
    /// Node-major: node `n`'s group `g` is texel `n · groups + g`.
    Rows,
    Tiles(TileMap),
    Bricks {
        map: BrickMap,
        atlas: [u32; 3],
        grid: [usize; 3],
        /// Per brick (x fastest): its atlas slot, [`NO_SLOT`] when empty.
        slots: Vec<u32>,
        /// Per axis, per node: the (brick, position) pairs that hold it, apron included.
        holders: [Vec<Vec<(u32, u32)>>; 3],
    },
}

impl ArrayStream {
    /// Starts `name`'s texture in `folder` (created if missing): `dims` nodes of `channels`
    /// values in `encoding` and `layout` (`live`, the live bricks, for [`ArrayLayout::Bricks`],
    /// whose indirection file is written at once), `ranges` one per channel.
    ///
    /// # Errors
    /// What [`Container::encode`] refuses; ranges other than one per channel; writing.
    pub fn create(
        folder: &Path,
        name: &str,
        dims: [u32; 3],
        channels: usize,
        encoding: Encoding,
        layout: ArrayLayout,
        live: Option<&LiveBricks>,
        ranges: Vec<ChannelRange>,
    ) -> Result<ArrayStream, TextureError> {
        if ranges.len() != channels {
            return Err(TextureError::LengthMismatch {
                what: "channel ranges",
                expected: channels,
                got: ranges.len(),
            });
        }
        let mut entry = new_entry(name, dims, channels, encoding, layout, live)?;
        let nodes = checked_product("array nodes", &dims.map(u64::from))?;
        if nodes == 0 || channels == 0 {
            return Err(TextureError::invalid(
                "array",
                format!("{name:?}: {dims:?} nodes of {channels} channels"),
            ));
        }
        std::fs::create_dir_all(folder).map_err(|e| TextureError::io(folder, e))?;
        let padded = entry.groups() * entry.group_size();
        let mut quantised_ranges = ranges.clone();
        if encoding.is_normalized() {
            entry.ranges = ranges;
            // The padding channels are zeros: their ranges as quantize fits them.
            let mut zeros = crate::RangeFit::new(1);
            zeros.add(&[0.0]);
            quantised_ranges.resize(padded, zeros.ranges(encoding)[0]);
        } else {
            quantised_ranges = vec![ChannelRange::IDENTITY; padded];
        }
        let shape = entry.texture_shape()?;
        let placement = match (&entry.bricks, live) {
            (Some(b), Some(live)) => {
                let live = live.live();
                // Written and dropped before the slots are made.
                let indirection_bytes = {
                    let indirection = indirection_texture(b, live)?.to_bytes()?;
                    crate::write_atomic(&folder.join(&b.indirection), &indirection)?;
                    indirection.len() as u64
                };
                let mut slot = 0u32;
                let slots = live
                    .iter()
                    .map(|&l| {
                        if l {
                            slot += 1;
                            slot - 1
                        } else {
                            NO_SLOT
                        }
                    })
                    .collect();
                let holders = [0, 1, 2].map(|a| {
                    let (d, g) = (dims[a], b.grid[a]);
                    let mut holders = vec![Vec::new(); d as usize];
                    for brick in 0..g {
                        for p in 0..=b.size {
                            let node = (brick * b.size + p).min(d - 1);
                            holders[node as usize].push((brick, p));
                        }
                    }
                    holders
                });
                let map = BrickMap::new(&entry, b, &shape);
                let placement = Placement::Bricks {
                    map,
                    atlas: b.atlas,
                    grid: b.grid.map(|g| g as usize),
                    slots,
                    holders,
                };
                if let Some(stored) = entry.bricks.as_mut() {
                    stored.indirection_bytes = indirection_bytes;
                }
                placement
            }
            _ => match TileMap::new(&entry, &shape) {
                Some(map) => Placement::Tiles(map),
                None => Placement::Rows,
            },
        };
        let (prefix, level) = Ktx2Texture::level_prefix(
            entry.texture_format(),
            shape,
            vec![(KEY_PRT_ARRAY, embedded_entry(&entry)?)],
        )?;
        entry.bytes = prefix.len() as u64 + level;
        entry.validate(&UNBOUNDED)?;
        let path = folder.join(&entry.file);
        let mut out = crate::atomic::AtomicFile::open(&path)?;
        // Texels no node reaches (unused tiles, empty atlas slots) stay zero.
        let file = out.file()?;
        file.write_all(&prefix)
            .and_then(|()| file.set_len(entry.bytes))
            .map_err(|e| TextureError::io(&path, e))?;
        Ok(ArrayStream {
            ranges: quantised_ranges,
            level_offset: prefix.len() as u64,
            placement,
            written: Vec::new(),
            written_nodes: 0,
            pending: Vec::new(),
            buffer: Vec::new(),
            entry,
            out,
        })
    }

    /// Writes the nodes of the box at node `min` of `size` nodes: `values` holds `channels`
    /// values per node of the box, x fastest.
    ///
    /// # Errors
    /// A box outside the array or with a node already written; values of another length,
    /// non-finite or outside the encoding's range; writing.
    pub fn write_block(
        &mut self,
        min: [u32; 3],
        size: [u32; 3],
        values: &[f32],
    ) -> Result<(), TextureError> {
        let dims = self.entry.dims;
        let name = self.entry.name.clone();
        if (0..3).any(|a| u64::from(min[a]) + u64::from(size[a]) > u64::from(dims[a])) {
            return Err(TextureError::invalid(
                "array block",
                format!("{size:?} nodes at {min:?} outside {name:?}'s {dims:?}"),
            ));
        }
        let [sx, sy, sz] = size.map(|s| s as usize);
        let channels = self.entry.channels;
        if values.len() != sx * sy * sz * channels {
            return Err(TextureError::LengthMismatch {
                what: "array block values",
                expected: sx * sy * sz * channels,
                got: values.len(),
            });
        }
        if size.iter().all(|&s| s > 0) {
            let overlaps = |&&(m, z): &&([u32; 3], [u32; 3])| {
                (0..3).all(|a| min[a] < m[a] + z[a] && m[a] < min[a] + size[a])
            };
            if let Some(&(m, _)) = self.written.iter().find(overlaps) {
                let node = [0, 1, 2].map(|a| min[a].max(m[a]));
                return Err(TextureError::invalid(
                    "array block",
                    format!("node {node:?} of {name:?} written twice"),
                ));
            }
            self.written.push((min, size));
            self.written_nodes += (sx * sy * sz) as u64;
        }
        let (groups, padded) = (self.entry.groups(), self.ranges.len());
        let mut padded_values = vec![0.0f32; sx * sy * sz * padded];
        for (dst, src) in padded_values
            .chunks_exact_mut(padded)
            .zip(values.chunks_exact(channels))
        {
            dst[..channels].copy_from_slice(src);
        }
        let q = if self.entry.encoding == Encoding::Rgb9e5 {
            // Shared-exponent texels hold 3 channels each.
            crate::quantize_with_ranges(&padded_values, 3, self.entry.encoding, self.ranges.clone())
        } else {
            crate::quantize_with_ranges(
                &padded_values,
                padded,
                self.entry.encoding,
                self.ranges.clone(),
            )
        }?;
        drop(padded_values);
        let texel = self.entry.texture_format().bytes_per_texel();
        let [nx, ny, _] = dims.map(|d| d as usize);
        for (local, node_texels) in q.bytes.chunks_exact(groups * texel).enumerate() {
            let node = [
                min[0] as usize + local % sx,
                min[1] as usize + local / sx % sy,
                min[2] as usize + local / (sx * sy),
            ];
            let n = node[0] + nx * (node[1] + ny * node[2]);
            for (g, bytes) in node_texels.chunks_exact(texel).enumerate() {
                match &self.placement {
                    Placement::Rows => self.pending.push((
                        self.level_offset + ((n * groups + g) * texel) as u64,
                        self.buffer.len() / texel,
                    )),
                    Placement::Tiles(map) => self.pending.push((
                        self.level_offset + (map.texel(n, g) * texel) as u64,
                        self.buffer.len() / texel,
                    )),
                    Placement::Bricks {
                        map,
                        atlas,
                        grid,
                        slots,
                        holders,
                    } => {
                        for &(bz, pz) in &holders[2][node[2]] {
                            for &(by, py) in &holders[1][node[1]] {
                                for &(bx, px) in &holders[0][node[0]] {
                                    let brick = bx as usize
                                        + grid[0] * (by as usize + grid[1] * bz as usize);
                                    let slot = slots[brick];
                                    if slot != NO_SLOT {
                                        let at = slot_coordinate(slot as usize, *atlas);
                                        let to = map.texel(at, [px, py, pz], g) * texel;
                                        self.pending.push((
                                            self.level_offset + to as u64,
                                            self.buffer.len() / texel,
                                        ));
                                    }
                                }
                            }
                        }
                    }
                }
                self.buffer.extend_from_slice(bytes);
            }
            let held = self.buffer.len() + self.pending.len() * size_of::<(u64, usize)>();
            if held >= STREAM_BUFFER_BYTES {
                self.flush()?;
            }
        }
        Ok(())
    }

    /// Writes the pending texels, sorted by offset, contiguous runs in one write each.
    fn flush(&mut self) -> Result<(), TextureError> {
        use std::io::{Seek, SeekFrom, Write};
        let texel = self.entry.texture_format().bytes_per_texel();
        let path = self.out.path().to_path_buf();
        let file = self.out.file()?;
        self.pending.sort_unstable();
        let mut run: Vec<u8> = Vec::new();
        let mut run_start = 0u64;
        for &(offset, at) in &self.pending {
            if run.is_empty() || offset != run_start + run.len() as u64 {
                if !run.is_empty() {
                    file.seek(SeekFrom::Start(run_start))
                        .and_then(|_| file.write_all(&run))
                        .map_err(|e| TextureError::io(&path, e))?;
                }
                run.clear();
                run_start = offset;
            }
            run.extend_from_slice(&self.buffer[at * texel..(at + 1) * texel]);
        }
        if !run.is_empty() {
            file.seek(SeekFrom::Start(run_start))
                .and_then(|_| file.write_all(&run))
                .map_err(|e| TextureError::io(&path, e))?;
        }
        self.pending.clear();
        self.buffer.clear();
        Ok(())
    }

    /// Writes what is pending, checks that every node was written, and renames the file into
    /// place; returns the array's manifest entry.
    ///
    /// # Errors
    /// A node never written; writing.
    pub fn finish(mut self) -> Result<ArrayEntry, TextureError> {
        self.flush()?;
        let nodes: u64 = self.entry.dims.iter().map(|&d| u64::from(d)).product();
        let written = self.written_nodes;
        if written != nodes {
            return Err(TextureError::invalid(
                "array stream",
                format!(
                    "{} of {nodes} nodes of {:?} written",
                    written, self.entry.name
                ),
            ));
        }
        self.out.commit()?;
        Ok(self.entry)
    }
}

/// A container read back: the manifest and every array dequantised, in manifest order.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedContainer {
    /// The validated manifest.
    pub manifest: Manifest,
    /// `(name, values)` of every array.
    pub arrays: Vec<(String, GridArray)>,
}

impl LoadedContainer {
    /// The array called `name`.
    pub fn array(&self, name: &str) -> Option<&GridArray> {
        self.arrays.iter().find(|(n, _)| n == name).map(|(_, a)| a)
    }

    /// Reads a container folder written by [`Container::write`].
    pub fn read(folder: &Path, limits: &Limits) -> Result<LoadedContainer, TextureError> {
        let manifest =
            crate::atomic::read_limited(&folder.join(MANIFEST_FILE), MAX_MANIFEST_BYTES as u64)?;
        LoadedContainer::decode(&manifest, limits, |file| {
            crate::atomic::read_limited(
                &folder.join(file),
                limits.max_bytes.saturating_add(1 << 20),
            )
        })
    }

    /// Decodes a container from its manifest bytes and a loader of its files (by file name,
    /// already validated to be `<array name>.ktx2`). Every texture must match its manifest
    /// entry (format, shape, embedded entry).
    pub fn decode(
        manifest: &[u8],
        limits: &Limits,
        mut load: impl FnMut(&str) -> Result<Vec<u8>, TextureError>,
    ) -> Result<LoadedContainer, TextureError> {
        let manifest = Manifest::from_json(manifest, limits)?;
        let mut arrays = Vec::with_capacity(manifest.arrays.len());
        for entry in &manifest.arrays {
            let bytes = load(&entry.file)?;
            let texture = Ktx2Texture::from_bytes(&bytes, limits)?;
            let slots = match &entry.bricks {
                Some(bricks) => {
                    let bytes = load(&bricks.indirection)?;
                    let indirection = Ktx2Texture::from_bytes(&bytes, limits)?;
                    Some(brick_slots(entry, bricks, &indirection)?)
                }
                None => None,
            };
            arrays.push((
                entry.name.clone(),
                decode_array(entry, &texture, slots.as_deref())?,
            ));
        }
        Ok(LoadedContainer { manifest, arrays })
    }
}

/// Encodes an array's texture; `live` is the liveness of each brick of a brick-layout array.
fn encode_array(
    entry: &ArrayEntry,
    array: &GridArray,
    live: Option<&[bool]>,
) -> Result<(Ktx2Texture, Vec<ChannelRange>), TextureError> {
    let group = entry.group_size();
    let padded_channels = entry.groups() * group;
    let nodes = array.nodes();
    let mut padded = vec![0.0f32; nodes * padded_channels];
    for (dst, src) in padded
        .chunks_exact_mut(padded_channels)
        .zip(array.data.chunks_exact(array.channels))
    {
        dst[..array.channels].copy_from_slice(src);
    }
    let q = if entry.encoding == Encoding::Rgb9e5 {
        // Shared-exponent texels hold 3 channels each.
        quantize(&padded, 3, entry.encoding)?
    } else {
        quantize(&padded, padded_channels, entry.encoding)?
    };
    let texel_bytes = entry.texture_format().bytes_per_texel();
    let shape = entry.texture_shape()?;
    let bytes = match (TileMap::new(entry, &shape), &entry.bricks, live) {
        (_, Some(bricks), Some(live)) => {
            let map = BrickMap::new(entry, bricks, &shape);
            let mut out = vec![0u8; map.texels()? * texel_bytes];
            let groups = entry.groups();
            let side = bricks.size + 1;
            let [gx, gy, _] = bricks.grid.map(|g| g as usize);
            let slots = live.iter().enumerate().filter(|(_, l)| **l);
            for (slot, (b, _)) in slots.enumerate() {
                let brick = [b % gx, b / gx % gy, b / (gx * gy)].map(|i| i as u32);
                let at = slot_coordinate(slot, bricks.atlas);
                // Every texel of the brick, apron included: node b·B + p, clamped to the grid.
                for p in 0..side.pow(3) {
                    let p = [p % side, p / side % side, p / (side * side)];
                    let node = [0, 1, 2]
                        .map(|a| (brick[a] * bricks.size + p[a]).min(entry.dims[a] - 1) as usize);
                    let n = map.node_index(node);
                    for g in 0..groups {
                        let from = (n * groups + g) * texel_bytes;
                        let to = map.texel(at, p, g) * texel_bytes;
                        out[to..to + texel_bytes]
                            .copy_from_slice(&q.bytes[from..from + texel_bytes]);
                    }
                }
            }
            out
        }
        (None, _, _) => q.bytes,
        (Some(map), _, _) => {
            // node-major [node][group] → each group's texels in its tile (unused tiles stay 0)
            let groups = entry.groups();
            let texels = checked_product(
                "atlas texels",
                &[shape.width, shape.height, shape.depth].map(u64::from),
            )?;
            let mut out = vec![0u8; texels as usize * texel_bytes];
            for (node, node_texels) in q.bytes.chunks_exact(groups * texel_bytes).enumerate() {
                for (g, texel) in node_texels.chunks_exact(texel_bytes).enumerate() {
                    let at = map.texel(node, g) * texel_bytes;
                    out[at..at + texel_bytes].copy_from_slice(texel);
                }
            }
            out
        }
    };
    let texture = Ktx2Texture::new(entry.texture_format(), shape, vec![bytes])?;
    let ranges = if entry.encoding.is_normalized() {
        q.ranges[..array.channels].to_vec()
    } else {
        Vec::new()
    };
    Ok((texture, ranges))
}

/// Decodes an array's texture; `slots` is the atlas brick of each brick of a brick-layout array.
fn decode_array(
    entry: &ArrayEntry,
    texture: &Ktx2Texture,
    slots: Option<&[Option<[usize; 3]>]>,
) -> Result<GridArray, TextureError> {
    let format = entry.texture_format();
    if texture.format() != format || texture.shape() != entry.texture_shape()? {
        return Err(TextureError::malformed(
            "container texture",
            format!(
                "{} does not have the format and shape its manifest entry announces",
                entry.file
            ),
        ));
    }
    let embedded: Option<ArrayEntry> = texture
        .key(KEY_PRT_ARRAY)
        .and_then(|json| serde_json::from_slice(json).ok());
    if let Some(embedded) = embedded {
        let same = embedded.name == entry.name
            && embedded.dims == entry.dims
            && embedded.channels == entry.channels
            && embedded.encoding == entry.encoding
            && embedded.layout == entry.layout
            && embedded.single_channel == entry.single_channel
            && embedded.bricks == entry.bricks
            // Version 3 and earlier embedded the ranges too.
            && (embedded.ranges.is_empty()
                || (0..entry.channels).all(|c| embedded.range(c) == entry.range(c)));
        if !same {
            return Err(TextureError::malformed(
                "container texture",
                format!("{} belongs to another manifest", entry.file),
            ));
        }
    }
    let level = &texture.levels()[0];
    let groups = entry.groups();
    let group = entry.group_size();
    let texel_bytes = format.bytes_per_texel();
    let nodes = entry.dims.iter().map(|&d| d as usize).product::<usize>();
    // Nodes of empty bricks, which read back as 0 whatever the encoding's decode of zero bytes.
    let mut empty = Vec::new();
    let node_major = match (TileMap::new(entry, &texture.shape()), &entry.bricks, slots) {
        (_, Some(bricks), Some(slots)) => {
            let map = BrickMap::new(entry, bricks, &texture.shape());
            if level.len() != map.texels()? * texel_bytes {
                return Err(TextureError::malformed(
                    "container texture",
                    format!("{} is not as long as its shape", entry.file),
                ));
            }
            let mut out = vec![0u8; nodes * groups * texel_bytes];
            for (n, node_texels) in out.chunks_exact_mut(groups * texel_bytes).enumerate() {
                let node = map.node(n);
                let mut brick = 0;
                let mut p = [0u32; 3];
                for a in (0..3).rev() {
                    let (b, q) = brick_of(node[a], bricks.size, bricks.grid[a]);
                    brick = brick * bricks.grid[a] as usize + b as usize;
                    p[a] = q;
                }
                match slots[brick] {
                    Some(at) => {
                        for (g, texel) in node_texels.chunks_exact_mut(texel_bytes).enumerate() {
                            let from = map.texel(at, p, g) * texel_bytes;
                            texel.copy_from_slice(&level[from..from + texel_bytes]);
                        }
                    }
                    None => empty.push(n),
                }
            }
            out
        }
        (None, _, _) => level.clone(),
        (Some(map), _, _) => {
            let mut out = vec![0u8; nodes * groups * texel_bytes];
            for (i, texel) in out.chunks_exact_mut(texel_bytes).enumerate() {
                let at = map.texel(i / groups, i % groups) * texel_bytes;
                // Inside when the level matches its shape, which the KTX2 reader checks.
                let src = level.get(at..at + texel_bytes).ok_or_else(|| {
                    TextureError::malformed(
                        "container texture",
                        format!("{} is shorter than its shape", entry.file),
                    )
                })?;
                texel.copy_from_slice(src);
            }
            out
        }
    };
    let padded_channels = groups * group;
    let ranges = (0..padded_channels)
        .map(|c| {
            if c < entry.channels {
                entry.range(c)
            } else {
                ChannelRange {
                    scale: 0.0,
                    bias: 0.0,
                }
            }
        })
        .collect();
    let values = dequantize(&Quantized {
        encoding: entry.encoding,
        channels: padded_channels,
        ranges,
        bytes: node_major,
    })?;
    let mut data = Vec::with_capacity(nodes * entry.channels);
    for node in values.chunks_exact(padded_channels) {
        data.extend_from_slice(&node[..entry.channels]);
    }
    for n in empty {
        data[n * entry.channels..(n + 1) * entry.channels].fill(0.0);
    }
    GridArray::new(entry.dims, entry.channels, data)
}

/// The indirection texture of a brick layout: RGBA8 unorm, one texel per brick, `(x, y, z, 255)`
/// for a live brick at atlas brick `(x, y, z)`, zeros for an empty one.
fn indirection_texture(bricks: &Bricks, live: &[bool]) -> Result<Ktx2Texture, TextureError> {
    let mut bytes = vec![0u8; live.len() * 4];
    let slots = live.iter().enumerate().filter(|(_, l)| **l);
    for (slot, (b, _)) in slots.enumerate() {
        let at = slot_coordinate(slot, bricks.atlas);
        // Below MAX_ATLAS_BRICKS = 256 (brick_atlas checks it).
        bytes[4 * b..4 * b + 4].copy_from_slice(&[at[0] as u8, at[1] as u8, at[2] as u8, 255]);
    }
    let [gx, gy, gz] = bricks.grid;
    Ktx2Texture::new(
        PixelFormat::R8G8B8A8Unorm,
        Shape::d3(gx, gy, gz),
        vec![bytes],
    )
}

/// The atlas brick of every brick, from the indirection texture, checked against the entry:
/// the format and shape, `live` live bricks, each inside the atlas and in its own slot.
fn brick_slots(
    entry: &ArrayEntry,
    bricks: &Bricks,
    texture: &Ktx2Texture,
) -> Result<Vec<Option<[usize; 3]>>, TextureError> {
    let bad = |why: &str| {
        Err(TextureError::malformed(
            "container texture",
            format!("{}: {why}", bricks.indirection),
        ))
    };
    let [gx, gy, gz] = bricks.grid;
    if texture.format() != PixelFormat::R8G8B8A8Unorm || texture.shape() != Shape::d3(gx, gy, gz) {
        return bad("not an RGBA8 texture of one texel per brick");
    }
    let [ax, ay, az] = bricks.atlas.map(|a| a as usize);
    let mut used = vec![false; ax * ay * az];
    let mut slots = Vec::with_capacity(texture.levels()[0].len() / 4);
    for texel in texture.levels()[0].chunks_exact(4) {
        slots.push(match texel {
            [0, 0, 0, 0] => None,
            &[x, y, z, 255] => {
                let at = [x, y, z].map(usize::from);
                if at[0] >= ax || at[1] >= ay || at[2] >= az {
                    return bad("a brick outside the atlas");
                }
                let slot = &mut used[at[0] + ax * (at[1] + ay * at[2])];
                if std::mem::replace(slot, true) {
                    return bad("two bricks in one atlas slot");
                }
                Some(at)
            }
            _ => return bad("a texel that is neither a brick nor empty"),
        });
    }
    let live = slots.iter().filter(|s| s.is_some()).count() as u64;
    if live != bricks.live || slots.len() != entry_bricks(entry) {
        return bad("a live-brick count other than the manifest's");
    }
    Ok(slots)
}

/// Bricks of a brick-layout entry.
fn entry_bricks(entry: &ArrayEntry) -> usize {
    entry
        .bricks
        .as_ref()
        .map_or(0, |b| b.grid.iter().map(|&g| g as usize).product())
}

/// Where node `(i, j, k)`'s group `g` lives in a brick atlas.
#[derive(Debug)]
struct BrickMap {
    dims: [usize; 3],
    side: usize,
    /// Texels of one group's atlas along z (groups are stacked along z).
    group_depth: usize,
    texture: [usize; 3],
}

impl BrickMap {
    fn new(entry: &ArrayEntry, bricks: &Bricks, shape: &Shape) -> BrickMap {
        let side = bricks.size as usize + 1;
        BrickMap {
            dims: entry.dims.map(|d| d as usize),
            side,
            group_depth: bricks.atlas[2] as usize * side,
            texture: [shape.width, shape.height, shape.depth].map(|d| d as usize),
        }
    }

    fn texels(&self) -> Result<usize, TextureError> {
        Ok(checked_product("brick atlas texels", &self.texture.map(|t| t as u64))? as usize)
    }

    fn node(&self, n: usize) -> [u32; 3] {
        let [nx, ny, _] = self.dims;
        [n % nx, n / nx % ny, n / (nx * ny)].map(|i| i as u32)
    }

    fn node_index(&self, node: [usize; 3]) -> usize {
        node[0] + self.dims[0] * (node[1] + self.dims[1] * node[2])
    }

    /// Flat texel index (x fastest) of texel `p` of the brick at atlas brick `at`, group `g`.
    fn texel(&self, at: [usize; 3], p: [u32; 3], g: usize) -> usize {
        let [x, y, z] = [0, 1, 2].map(|a| at[a] * self.side + p[a] as usize);
        let z = z + g * self.group_depth;
        x + self.texture[0] * (y + self.texture[1] * z)
    }
}

/// Where node `n`'s group `g` lives in a tiled (filterable) texture.
#[derive(Debug)]
struct TileMap {
    dims: [usize; 3],
    tiles: [usize; 2],
    texture: [usize; 2],
}

impl TileMap {
    /// The map of a filterable layout; `None` for [`ArrayLayout::Rows`].
    fn new(entry: &ArrayEntry, shape: &Shape) -> Option<TileMap> {
        let [tx, ty, _] = entry.tile_grid()?.map(|t| t as usize);
        Some(TileMap {
            dims: entry.dims.map(|d| d as usize),
            tiles: [tx, ty],
            texture: [shape.width as usize, shape.height as usize],
        })
    }

    /// Flat texel index (x fastest) of node `node`'s channel group `g`.
    fn texel(&self, node: usize, g: usize) -> usize {
        let [nx, ny, nz] = self.dims;
        let (i, j, k) = (node % nx, node / nx % ny, node / (nx * ny));
        let [tx, ty] = self.tiles;
        let (gx, gy, gz) = (g % tx, g / tx % ty, g / (tx * ty));
        let (x, y, z) = (gx * nx + i, gy * ny + j, gz * nz + k);
        x + self.texture[0] * (y + self.texture[1] * z)
    }
}
