//! The MBD container: writing a fitted model in the filterable layout and reading it back as a
//! model that evaluates f̂.

use std::collections::BTreeMap;
use std::path::Path;

use glam::Vec3;
use ndarray::{Array2, Array3};
use prt_core::{Aabb, SpatialKernels};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_texture::container::{
    ArrayLayout, ArrayStream, BrickRequest, Container, DEFAULT_BRICK_SIZE, GridArray,
    KernelDescription, LiveBricks, LoadedContainer, MBD_BASIS, MBD_COEFFICIENTS, Manifest,
    WriteReport,
};
use prt_texture::{Encoding, Limits, RangeFit};
use serde_json::json;

pub use crate::error::ContainerError;

/// Name of the validity array.
pub const VALIDITY: &str = "validity";
/// Value of the `model` attribute of an MBD container.
pub const MBD_MODEL: &str = "moving basis decomposition";
/// Kernel kind of a trilinear hat grid.
const HAT: &str = "hat";
/// The smallest saving of coefficient-volume bytes for which [`CoefficientLayout::Auto`] picks
/// bricks: below it the dense volume is kept (it costs a shader no indirection fetch).
pub const BRICK_MIN_SAVING: f64 = 0.25;

/// How [`write_container_with`] lays out the coefficient volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CoefficientLayout {
    /// Bricks when they save at least [`BRICK_MIN_SAVING`] of the dense volume's texel bytes,
    /// dense otherwise (small or mostly valid scenes).
    #[default]
    Auto,
    /// Always the dense `volume` layout.
    Dense,
    /// Always the `bricks` layout (docs/formats.md, "Brick layout").
    Bricks,
}

/// The coefficient layout [`write_container_with`] writes and which nodes it must keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayoutConfig<'a> {
    /// Dense, bricks or the rule.
    pub layout: CoefficientLayout,
    /// Cells per brick edge (1 ..= 64).
    pub brick_size: u32,
    /// Per coefficient node (x fastest): whether its value must be stored (a node whose hat
    /// support reaches a valid voxel). `None`: derived from the validity by [`node_liveness`].
    pub live_nodes: Option<&'a [bool]>,
}

impl Default for LayoutConfig<'_> {
    fn default() -> Self {
        LayoutConfig {
            layout: CoefficientLayout::Auto,
            brick_size: DEFAULT_BRICK_SIZE,
            live_nodes: None,
        }
    }
}

/// Texel bytes of the coefficient volume in each layout, as [`CoefficientLayout::Auto`] weighs
/// them (textures' level 0; headers and manifest excluded).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayoutBytes {
    /// The dense `volume` layout.
    pub dense: u64,
    /// The `bricks` layout: the atlas of live bricks plus the indirection (4 bytes per brick).
    pub bricks: u64,
    /// Live bricks of all bricks.
    pub live_bricks: u64,
    /// All bricks.
    pub bricks_total: u64,
}

impl LayoutBytes {
    /// The texel bytes of a coefficient volume of `rank` channels in `encoding`, dense and in
    /// the bricks `live` holds live.
    pub fn of(rank: usize, encoding: Encoding, live: &LiveBricks) -> LayoutBytes {
        let format = encoding.rgba_format();
        let texel = (format.bytes_per_texel() * rank.div_ceil(format.channels())) as u64;
        let live_count = live.count();
        let side = u64::from(live.size()) + 1;
        LayoutBytes {
            dense: live.dims().iter().map(|&n| u64::from(n)).product::<u64>() * texel,
            bricks: live_count * side.pow(3) * texel + 4 * live.live().len() as u64,
            live_bricks: live_count,
            bricks_total: live.live().len() as u64,
        }
    }

    /// Whether the rule picks bricks: they save at least [`BRICK_MIN_SAVING`].
    pub fn bricks_pay(&self) -> bool {
        (self.bricks as f64) <= (1.0 - BRICK_MIN_SAVING) * self.dense as f64
    }
}

/// The texel bytes of a coefficient volume of `nodes`, `rank` channels in `encoding`, dense and
/// in bricks of `brick_size` cells keeping `live_nodes`.
pub fn layout_bytes(
    nodes: [usize; 3],
    rank: usize,
    encoding: Encoding,
    brick_size: u32,
    live_nodes: &[bool],
) -> Result<LayoutBytes, ContainerError> {
    let live = LiveBricks::of_nodes(nodes.map(|n| n as u32), brick_size, live_nodes)?;
    Ok(LayoutBytes::of(rank, encoding, &live))
}

/// The coefficient nodes voxel `i` of `g` along an axis of `n` nodes touches (the first
/// `.1` of `.0`), in node coordinates `p = i (n − 1) / (g − 1)`: the nodes whose open hat
/// support holds the voxel's centre.
fn touched_nodes(n: usize, g: usize, i: usize) -> ([usize; 2], usize) {
    if n == 1 {
        return ([0, 0], 1);
    }
    let p = if g > 1 {
        i as f64 * (n - 1) as f64 / (g - 1) as f64
    } else {
        0.0
    };
    let lo = (p.floor() as usize).min(n - 1);
    if p - lo as f64 > 0.0 && lo + 1 < n {
        ([lo, lo + 1], 2)
    } else {
        ([lo, lo], 1)
    }
}

/// Which nodes of a coefficient hat grid are live: those whose hat support (open) holds the
/// centre of a valid voxel of `grid`, the voxel centres spanning the kernels' domain (as
/// `prt bake` fits them: node i at voxel centre i when the grids agree).
pub fn node_liveness(
    kernels: &HatGrid,
    grid: [usize; 3],
    valid: &[bool],
) -> Result<Vec<bool>, ContainerError> {
    let voxels = grid.iter().product::<usize>();
    if valid.len() != voxels {
        return Err(ContainerError::Inconsistent(format!(
            "{} validity flags for {voxels} voxels",
            valid.len()
        )));
    }
    let nodes = kernels.nodes();
    if nodes == grid {
        return Ok(valid.to_vec());
    }
    let touched = |a: usize, i: usize| {
        let (nodes, count) = touched_nodes(nodes[a], grid[a], i);
        nodes.into_iter().take(count)
    };
    let mut live = vec![false; nodes.iter().product()];
    for (v, _) in valid.iter().enumerate().filter(|(_, ok)| **ok) {
        let (i, j, k) = (v % grid[0], v / grid[0] % grid[1], v / (grid[0] * grid[1]));
        for z in touched(2, k) {
            for y in touched(1, j) {
                for x in touched(0, i) {
                    live[x + nodes[0] * (y + nodes[1] * z)] = true;
                }
            }
        }
    }
    Ok(live)
}

/// What [`write_container`] stores: a fitted model, the validity of the baked voxels and a
/// little provenance.
#[derive(Debug, Clone, Copy)]
pub struct ContainerContents<'a> {
    /// The model.
    pub model: &'a MbdModel<HatGrid, HatGrid>,
    /// Voxels of the baked grid along x, y, z.
    pub grid: [usize; 3],
    /// Per voxel of `grid` (x fastest): whether its transfer is meaningful (not inside geometry).
    pub valid: &'a [bool],
    /// The scene's name (the `scene` attribute).
    pub scene: &'a str,
    /// The ridge weight the model was fitted with (the `lambda` attribute).
    pub lambda: f32,
    /// Encoding of the coefficient and basis volumes (validity is always 8-bit).
    pub encoding: Encoding,
}

/// A container read back: the model, the validity mask and the manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct MbdContainer {
    /// The model, evaluating f̂(x) (it implements [`prt_core::FieldModel`]).
    pub model: MbdModel<HatGrid, HatGrid>,
    /// Voxels of the baked grid along x, y, z.
    pub grid: [usize; 3],
    /// Per voxel of `grid` (x fastest): whether its transfer is meaningful.
    pub valid: Vec<bool>,
    /// Encoding the coefficient volume was stored with.
    pub encoding: Encoding,
    /// The validated manifest, with every attribute (`scene`, `lambda`, layouts, ...).
    pub manifest: Manifest,
}

impl MbdContainer {
    /// A string attribute of the manifest (`scene`, `model`, ...).
    pub fn attribute_str(&self, key: &str) -> Option<&str> {
        self.manifest.attributes.get(key).and_then(|v| v.as_str())
    }
}

/// The manifest's description of a kernel family of `kind` with `nodes` over `domain`.
pub(crate) fn kernel_description(kind: &str, nodes: [usize; 3], domain: Aabb) -> KernelDescription {
    KernelDescription {
        kind: kind.into(),
        nodes: nodes.map(|n| n as u32),
        domain_min: domain.min.to_array(),
        domain_max: domain.max.to_array(),
    }
}

/// The encoding the manifest gives the coefficient array: the container's encoding.
pub(crate) fn coefficient_encoding(manifest: &Manifest) -> Result<Encoding, ContainerError> {
    manifest
        .arrays
        .iter()
        .find(|a| a.name == MBD_COEFFICIENTS)
        .map(|a| a.encoding)
        .ok_or(ContainerError::Missing {
            kind: "array",
            name: MBD_COEFFICIENTS,
        })
}

/// The description of a hat grid.
fn hat_description(kernels: &HatGrid) -> KernelDescription {
    kernel_description(HAT, kernels.nodes(), kernels.domain())
}

/// Writes the container into `folder` (created if missing), each file atomically and the
/// manifest last, in the filterable layout (docs/formats.md), the coefficients laid out by
/// [`CoefficientLayout::Auto`] with the nodes [`node_liveness`] derives from the validity; see
/// [`write_container_with`].
pub fn write_container(
    folder: &Path,
    contents: &ContainerContents<'_>,
) -> Result<WriteReport, ContainerError> {
    write_container_with(folder, contents, &LayoutConfig::default())
}

/// Writes the container into `folder` (created if missing), each file atomically and the
/// manifest last, in the filterable layout (docs/formats.md): `coefficients.ktx2` (the L
/// coefficients per node in ⌈L/4⌉ RGBA tiles stacked along z, [`ArrayLayout::Volume`], or in
/// bricks, [`ArrayLayout::Bricks`], with `coefficients.bricks.ktx2`, as `layout` says),
/// `basis.ktx2` (the 324·L basis values per basis node in 81·L RGBA tiles,
/// [`ArrayLayout::Atlas`]), `validity.ktx2` and `manifest.json`. Node `i` of a hat grid is
/// texel `i` of its tile, so hardware trilinear filtering at texel centres computes the hat
/// sums. Returns what was written (bytes included).
pub fn write_container_with(
    folder: &Path,
    contents: &ContainerContents<'_>,
    layout: &LayoutConfig<'_>,
) -> Result<WriteReport, ContainerError> {
    let model = contents.model;
    let coefficient_kernels = model.coefficient_kernels();
    let basis_kernels = model.basis_kernels();
    let (_, rank, _) = model.basis().dim();
    let coefficients = GridArray::new(
        coefficient_kernels.nodes().map(|n| n as u32),
        rank,
        model.coefficients().iter().copied().collect(),
    )?;
    let live_nodes = match layout.live_nodes {
        Some(live) => live.to_vec(),
        None => node_liveness(coefficient_kernels, contents.grid, contents.valid)?,
    };
    let live = LiveBricks::of_nodes(
        coefficient_kernels.nodes().map(|n| n as u32),
        layout.brick_size,
        &live_nodes,
    )?;
    let parts = MbdParts::new(
        &ContainerParts {
            coefficient_kernels,
            basis_kernels,
            basis: model.basis(),
            grid: contents.grid,
            scene: contents.scene,
            lambda: contents.lambda,
            encoding: contents.encoding,
        },
        layout.layout,
        &live,
    )?;
    let coefficient_layout = parts.coefficient_layout;
    let mut container = parts.into_container();
    if coefficient_layout == ArrayLayout::Bricks {
        container.bricks.insert(
            MBD_COEFFICIENTS.to_string(),
            BrickRequest {
                size: layout.brick_size,
                live_nodes,
            },
        );
    }
    container.arrays.insert(
        0,
        (
            MBD_COEFFICIENTS.to_string(),
            coefficients,
            contents.encoding,
            coefficient_layout,
        ),
    );
    container.arrays.push((
        VALIDITY.to_string(),
        validity_array(contents.grid, contents.valid)?,
        Encoding::Unorm8,
        ArrayLayout::Volume,
    ));
    Ok(container.write(folder)?)
}

/// The validity as an array (1 valid, 0 not).
fn validity_array(grid: [usize; 3], valid: &[bool]) -> Result<GridArray, ContainerError> {
    Ok(GridArray::new(
        grid.map(|n| n as u32),
        1,
        valid.iter().map(|&v| if v { 1.0 } else { 0.0 }).collect(),
    )?)
}

/// What an MBD container holds besides its coefficient and validity arrays: the attributes,
/// the kernels, the basis, and the coefficients' layout.
struct MbdParts {
    attributes: BTreeMap<String, serde_json::Value>,
    kernels: BTreeMap<String, KernelDescription>,
    basis: GridArray,
    encoding: Encoding,
    coefficient_layout: ArrayLayout,
}

impl MbdParts {
    /// The parts of `contents`, the coefficients laid out as `layout` says given the bricks
    /// `live` holds live.
    fn new(
        contents: &ContainerParts<'_>,
        layout: CoefficientLayout,
        live: &LiveBricks,
    ) -> Result<MbdParts, ContainerError> {
        let (coefficient_kernels, basis_kernels) =
            (contents.coefficient_kernels, contents.basis_kernels);
        let (_, rank, dim) = contents.basis.dim();
        let basis = GridArray::new(
            basis_kernels.nodes().map(|n| n as u32),
            rank * dim,
            contents.basis.iter().copied().collect(),
        )?;
        let mut attributes = BTreeMap::new();
        attributes.insert("model".into(), json!(MBD_MODEL));
        attributes.insert("scene".into(), json!(contents.scene));
        attributes.insert("rank".into(), json!(rank));
        attributes.insert("dimension".into(), json!(dim));
        attributes.insert(
            "vector_layout".into(),
            json!("[direct 9x9 | indirect R 9x9 | G 9x9 | B 9x9], each row-major T[i*9+j], i = incident-radiance SH, j = sky SH"),
        );
        attributes.insert(
            "basis_channel_order".into(),
            json!("channel = l * dimension + d (rank-major)"),
        );
        attributes.insert(
            "texture_coordinates".into(),
            json!("hat node i = texel centre i of its tile: uvw = (tile * nodes + clamp((x - domain_min) / (domain_max - domain_min), 0, 1) * (nodes - 1) + 0.5) / texture_size"),
        );
        attributes.insert("lambda".into(), json!(contents.lambda));
        attributes.insert(
            "validity".into(),
            json!("1 = valid voxel, 0 = inside geometry or outside the scene"),
        );
        let mut kernels = BTreeMap::new();
        kernels.insert(
            MBD_COEFFICIENTS.to_string(),
            hat_description(coefficient_kernels),
        );
        kernels.insert(MBD_BASIS.to_string(), hat_description(basis_kernels));
        let encoding = contents.encoding;
        if live.dims() != coefficient_kernels.nodes().map(|n| n as u32) {
            return Err(ContainerError::Inconsistent(format!(
                "live bricks of {:?} nodes for a coefficient grid of {:?}",
                live.dims(),
                coefficient_kernels.nodes()
            )));
        }
        let use_bricks = match layout {
            CoefficientLayout::Dense => false,
            CoefficientLayout::Bricks => true,
            CoefficientLayout::Auto => LayoutBytes::of(rank, encoding, live).bricks_pay(),
        };
        let coefficient_layout = if use_bricks {
            attributes.insert(
                "live_nodes".into(),
                json!("coefficient nodes whose hat support holds a valid voxel centre; the bricks without one read as 0"),
            );
            attributes.insert(
                "texture_coordinates".into(),
                json!("hat node coordinate p = clamp((x - domain_min) / (domain_max - domain_min), 0, 1) * (nodes - 1); brick b = min(floor(p / size), grid - 1); its indirection texel (x, y, z, live) * 255 gives the atlas brick a; uvw = (a * (size + 1) + p - b * size + 0.5 + (0, 0, group * atlas_z * (size + 1))) / texture_size"),
            );
            ArrayLayout::Bricks
        } else {
            ArrayLayout::Volume
        };
        Ok(MbdParts {
            attributes,
            kernels,
            basis,
            encoding,
            coefficient_layout,
        })
    }

    /// The container of the basis alone, with the attributes and kernels.
    fn into_container(self) -> Container {
        Container {
            bricks: BTreeMap::new(),
            attributes: self.attributes,
            kernels: self.kernels,
            arrays: vec![(
                MBD_BASIS.to_string(),
                self.basis,
                self.encoding,
                ArrayLayout::Atlas,
            )],
        }
    }
}

/// An MBD container's contents but the coefficients and the validity: the model's kernels and
/// basis, and the rest of [`ContainerContents`] (for [`ContainerWriter`]).
#[derive(Debug, Clone, Copy)]
pub struct ContainerParts<'a> {
    /// The coefficients' kernels (their nodes are the coefficient volume's).
    pub coefficient_kernels: &'a HatGrid,
    /// The basis's kernels.
    pub basis_kernels: &'a HatGrid,
    /// The basis, `basis nodes × L × D`.
    pub basis: &'a Array3<f32>,
    /// Voxels of the baked grid along x, y, z.
    pub grid: [usize; 3],
    /// The scene's name (the `scene` attribute).
    pub scene: &'a str,
    /// The ridge weight the model was fitted with (the `lambda` attribute).
    pub lambda: f32,
    /// Encoding of the coefficient and basis volumes (validity is always 8-bit).
    pub encoding: Encoding,
}

/// What [`ContainerWriter`] must know of the validity before it writes anything, gathered a box
/// of voxels at a time: how many voxels are valid and invalid (the validity's encoding range)
/// and which bricks of the coefficient grid hold a live node (as [`node_liveness`] derives
/// them), one flag per brick of the layout's brick size.
#[derive(Debug, Clone)]
pub struct ValiditySummary {
    grid: [usize; 3],
    /// Per axis, per voxel: the coefficient nodes it touches ([`touched_nodes`]).
    touched: [Vec<([usize; 2], usize)>; 3],
    live: LiveBricks,
    valid: u64,
    invalid: u64,
}

impl ValiditySummary {
    /// No voxel yet, of a grid of `grid` voxels whose coefficients live on `coefficient_kernels`,
    /// the coefficients' bricks of `brick_size` cells.
    ///
    /// # Errors
    /// A brick size outside `1..=64`; a grid too large to count.
    pub fn new(
        coefficient_kernels: &HatGrid,
        grid: [usize; 3],
        brick_size: u32,
    ) -> Result<ValiditySummary, ContainerError> {
        let nodes = coefficient_kernels.nodes();
        let live = LiveBricks::new(nodes.map(|n| n as u32), brick_size)?;
        let touched = [0, 1, 2].map(|a| {
            (0..grid[a])
                .map(|i| touched_nodes(nodes[a], grid[a], i))
                .collect()
        });
        Ok(ValiditySummary {
            grid,
            touched,
            live,
            valid: 0,
            invalid: 0,
        })
    }

    /// Bytes [`ValiditySummary::new`] allocates for a grid of `grid` voxels whose coefficient
    /// grid has `nodes` nodes, in bricks of `brick_size` cells: a flag per brick and, per axis
    /// and voxel, the nodes it touches (`u64::MAX` when it overflows).
    pub fn bytes_for(grid: [usize; 3], nodes: [usize; 3], brick_size: u32) -> u64 {
        let size = u64::from(brick_size.max(1));
        let bricks = nodes.iter().fold(1u64, |n, &d| {
            n.saturating_mul((d as u64).saturating_sub(1).div_ceil(size).max(1))
        });
        let per_voxel = size_of::<([usize; 2], usize)>() as u64;
        let tables = grid.iter().fold(0u64, |n, &g| {
            n.saturating_add((g as u64).saturating_mul(per_voxel))
        });
        bricks.saturating_add(tables)
    }

    /// Adds the validity of the box of voxels at `min` of `size` (x fastest).
    ///
    /// # Errors
    /// A box outside the grid; flags of another length than the box's voxels.
    pub fn add(
        &mut self,
        min: [usize; 3],
        size: [usize; 3],
        valid: &[bool],
    ) -> Result<(), ContainerError> {
        check_box(self.grid, min, size, valid.len())?;
        let [sx, sy, _] = size;
        for (local, _) in valid.iter().enumerate().filter(|(_, v)| **v) {
            let voxel = [
                min[0] + local % sx,
                min[1] + local / sx % sy,
                min[2] + local / (sx * sy),
            ];
            let [(xs, nx), (ys, ny), (zs, nz)] = [0, 1, 2].map(|a| self.touched[a][voxel[a]]);
            for &z in &zs[..nz] {
                for &y in &ys[..ny] {
                    for &x in &xs[..nx] {
                        self.live.mark([x, y, z].map(|n| n as u32))?;
                    }
                }
            }
        }
        let valid_here = valid.iter().filter(|&&v| v).count() as u64;
        self.valid += valid_here;
        self.invalid += valid.len() as u64 - valid_here;
        Ok(())
    }

    /// The valid voxels added.
    pub fn valid_voxels(&self) -> u64 {
        self.valid
    }

    /// The invalid voxels added.
    pub fn invalid_voxels(&self) -> u64 {
        self.invalid
    }
}

/// Checks a box at `min` of `size` lies in `grid` and `values` is its voxel count.
fn check_box(
    grid: [usize; 3],
    min: [usize; 3],
    size: [usize; 3],
    values: usize,
) -> Result<(), ContainerError> {
    if (0..3).any(|a| min[a].saturating_add(size[a]) > grid[a]) {
        return Err(ContainerError::Inconsistent(format!(
            "a box of {size:?} voxels at {min:?} outside the grid of {grid:?}"
        )));
    }
    if values != size.iter().product::<usize>() {
        return Err(ContainerError::Inconsistent(format!(
            "{values} validity flags for a box of {size:?} voxels"
        )));
    }
    Ok(())
}

/// Writes the container [`write_container_with`] writes with the coefficients and the validity
/// given a box at a time ([`ContainerWriter::write_coefficients`],
/// [`ContainerWriter::write_validity`]), for a model too large to hold: in memory bounded by a
/// box, the write buffers, the basis, a flag per coefficient brick ([`ValiditySummary`]) and,
/// in bricks, four bytes per brick. Both files are written under temporary names and renamed
/// once every node has been written exactly once, then the basis and the manifest (last) by
/// [`ContainerWriter::finish`].
#[derive(Debug)]
pub struct ContainerWriter {
    folder: std::path::PathBuf,
    coefficients: ArrayStream,
    validity: ArrayStream,
    container: Container,
    grid: [usize; 3],
    /// The valid voxels the summary counted, and those written.
    valid_voxels: u64,
    written_valid: u64,
}

impl ContainerWriter {
    /// Starts the container in `folder` (created if missing), the coefficients laid out as
    /// `layout` says (its brick size is `validity`'s); `ranges` of every coefficient channel
    /// over every node (zeros included), as the normalised encodings store them (unused by the
    /// others); `validity`, the summary of every voxel's validity.
    ///
    /// # Errors
    /// As [`write_container_with`]; a summary of another grid or not of every voxel once.
    pub fn create(
        folder: &Path,
        contents: &ContainerParts<'_>,
        ranges: &RangeFit,
        validity: &ValiditySummary,
        layout: CoefficientLayout,
    ) -> Result<ContainerWriter, ContainerError> {
        let voxels = contents.grid.iter().product::<usize>() as u64;
        if validity.grid != contents.grid || validity.valid + validity.invalid != voxels {
            return Err(ContainerError::Inconsistent(format!(
                "a validity summary of {} voxels on {:?} for a grid of {:?}",
                validity.valid + validity.invalid,
                validity.grid,
                contents.grid
            )));
        }
        let (_, rank, _) = contents.basis.dim();
        let parts = MbdParts::new(contents, layout, &validity.live)?;
        let mut validity_ranges = RangeFit::new(1);
        for (count, value) in [(validity.valid, 1.0), (validity.invalid, 0.0)] {
            if count > 0 {
                validity_ranges.add(&[value]);
            }
        }
        let validity_stream = ArrayStream::create(
            folder,
            VALIDITY,
            contents.grid.map(|n| u32::try_from(n).unwrap_or(u32::MAX)),
            1,
            Encoding::Unorm8,
            ArrayLayout::Volume,
            None,
            validity_ranges.ranges(Encoding::Unorm8),
        )?;
        let coefficients = ArrayStream::create(
            folder,
            MBD_COEFFICIENTS,
            contents.coefficient_kernels.nodes().map(|n| n as u32),
            rank,
            contents.encoding,
            parts.coefficient_layout,
            (parts.coefficient_layout == ArrayLayout::Bricks).then_some(&validity.live),
            ranges.ranges(contents.encoding),
        )?;
        Ok(ContainerWriter {
            folder: folder.to_path_buf(),
            coefficients,
            validity: validity_stream,
            container: parts.into_container(),
            grid: contents.grid,
            valid_voxels: validity.valid,
            written_valid: 0,
        })
    }

    /// Writes the coefficients of the box of nodes at `min` of `size` nodes: L values per node
    /// of the box, x fastest.
    ///
    /// # Errors
    /// A box outside the coefficient grid or with a node already written; values of another
    /// length, non-finite or outside the encoding's range; writing.
    pub fn write_coefficients(
        &mut self,
        min: [usize; 3],
        size: [usize; 3],
        coefficients: &[f32],
    ) -> Result<(), ContainerError> {
        Ok(self
            .coefficients
            .write_block(to_u32(min), to_u32(size), coefficients)?)
    }

    /// Writes the validity of the box of voxels at `min` of `size` (x fastest): the flags the
    /// summary was given for it.
    ///
    /// # Errors
    /// A box outside the grid or with a voxel already written; flags of another length;
    /// writing.
    pub fn write_validity(
        &mut self,
        min: [usize; 3],
        size: [usize; 3],
        valid: &[bool],
    ) -> Result<(), ContainerError> {
        check_box(self.grid, min, size, valid.len())?;
        let values: Vec<f32> = valid.iter().map(|&v| if v { 1.0 } else { 0.0 }).collect();
        self.validity
            .write_block(to_u32(min), to_u32(size), &values)?;
        self.written_valid += valid.iter().filter(|&&v| v).count() as u64;
        Ok(())
    }

    /// Writes the basis and the manifest once every coefficient node and every voxel's
    /// validity is written.
    ///
    /// # Errors
    /// A coefficient node or a voxel never written; validity other than the summary's;
    /// writing.
    pub fn finish(self) -> Result<WriteReport, ContainerError> {
        let coefficients = self.coefficients.finish()?;
        if self.written_valid != self.valid_voxels {
            return Err(ContainerError::Inconsistent(format!(
                "the validity written has {} valid voxels, its summary {}",
                self.written_valid, self.valid_voxels
            )));
        }
        let validity = self.validity.finish()?;
        Ok(self
            .container
            .write_with_streamed(&self.folder, vec![(0, coefficients), (2, validity)])?)
    }
}

/// A box's corner or size as the texture's u32 (saturating: a box beyond u32 is outside).
fn to_u32(v: [usize; 3]) -> [u32; 3] {
    v.map(|n| u32::try_from(n).unwrap_or(u32::MAX))
}

/// Reads a container written by [`write_container`] (or an older one with the basis in
/// [`ArrayLayout::Rows`]), decoding every texture through its layout, checking every file
/// against `limits` and the arrays against each other, the kernels and the attributes.
pub fn read_container(folder: &Path, limits: &Limits) -> Result<MbdContainer, ContainerError> {
    let loaded = LoadedContainer::read(folder, limits)?;
    from_loaded(loaded)
}

/// Builds the model from a container already loaded and dequantised.
fn from_loaded(loaded: LoadedContainer) -> Result<MbdContainer, ContainerError> {
    let manifest = &loaded.manifest;
    let model_kind = manifest.attributes.get("model").and_then(|v| v.as_str());
    if model_kind != Some(MBD_MODEL) {
        return Err(ContainerError::Inconsistent(format!(
            "the model attribute is {:?}, not {MBD_MODEL:?}",
            model_kind
        )));
    }
    let array = |name: &'static str| {
        loaded.array(name).ok_or(ContainerError::Missing {
            kind: "array",
            name,
        })
    };
    let (coefficients, basis, validity) = (
        array(MBD_COEFFICIENTS)?,
        array(MBD_BASIS)?,
        array(VALIDITY)?,
    );
    let coefficient_kernels = hat_grid(manifest, MBD_COEFFICIENTS, coefficients)?;
    let basis_kernels = hat_grid(manifest, MBD_BASIS, basis)?;
    let rank = coefficients.channels;
    if !basis.channels.is_multiple_of(rank) {
        return Err(ContainerError::Inconsistent(format!(
            "{} basis channels are not a multiple of the rank {rank}",
            basis.channels
        )));
    }
    let dim = basis.channels / rank;
    for (key, want) in [("rank", rank), ("dimension", dim)] {
        let stated = manifest.attributes.get(key).and_then(|v| v.as_u64());
        if stated != Some(want as u64) {
            return Err(ContainerError::Inconsistent(format!(
                "the {key} attribute is {stated:?}, the arrays say {want}"
            )));
        }
    }
    if validity.channels != 1 {
        return Err(ContainerError::Inconsistent(format!(
            "validity has {} channels, not 1",
            validity.channels
        )));
    }
    let encoding = coefficient_encoding(manifest)?;
    let shape_error = |e: ndarray::ShapeError| ContainerError::Inconsistent(e.to_string());
    let coefficients =
        Array2::from_shape_vec((coefficients.nodes(), rank), coefficients.data.clone())
            .map_err(shape_error)?;
    let basis = Array3::from_shape_vec((basis.nodes(), rank, dim), basis.data.clone())
        .map_err(shape_error)?;
    let model = MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)
        .map_err(ContainerError::Model)?;
    Ok(MbdContainer {
        model,
        grid: validity.dims.map(|d| d as usize),
        valid: validity.data.iter().map(|&v| v > 0.5).collect(),
        encoding,
        manifest: loaded.manifest,
    })
}

/// The hat grid a kernel description names; its nodes must be the array's.
fn hat_grid(
    manifest: &Manifest,
    name: &'static str,
    array: &GridArray,
) -> Result<HatGrid, ContainerError> {
    let description = manifest.kernels.get(name).ok_or(ContainerError::Missing {
        kind: "kernels",
        name,
    })?;
    if description.kind != HAT {
        return Err(ContainerError::Inconsistent(format!(
            "{name} kernels are {:?}, only {HAT:?} is supported",
            description.kind
        )));
    }
    if description.nodes != array.dims {
        return Err(ContainerError::Inconsistent(format!(
            "{name} kernels have {:?} nodes, the array {:?}",
            description.nodes, array.dims
        )));
    }
    // Not `Aabb::new`, which would silently swap corners given in the wrong order.
    let domain = Aabb {
        min: Vec3::from_array(description.domain_min),
        max: Vec3::from_array(description.domain_max),
    };
    HatGrid::new(description.nodes.map(|n| n as usize), domain).map_err(|source| {
        ContainerError::Kernels {
            which: name,
            source,
        }
    })
}
