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
    ArrayLayout, Container, GridArray, KernelDescription, LoadedContainer, MBD_BASIS,
    MBD_COEFFICIENTS, Manifest, WriteReport,
};
use prt_texture::{Encoding, Limits};
use serde_json::json;

use crate::ContainerError;

/// Name of the validity array.
pub const VALIDITY: &str = "validity";
/// Value of the `model` attribute of an MBD container.
pub const MBD_MODEL: &str = "moving basis decomposition";
/// Kernel kind of a trilinear hat grid.
const HAT: &str = "hat";

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
/// manifest last, in the filterable layout (docs/formats.md): `coefficients.ktx2` (the L
/// coefficients per node in ⌈L/4⌉ RGBA tiles stacked along z, [`ArrayLayout::Volume`]),
/// `basis.ktx2` (the 324·L basis values per basis node in 81·L RGBA tiles,
/// [`ArrayLayout::Atlas`]), `validity.ktx2` and `manifest.json`. Node `i` of a hat grid is
/// texel `i` of its tile, so hardware trilinear filtering at texel centres computes the hat
/// sums. Returns what was written (bytes included).
pub fn write_container(
    folder: &Path,
    contents: &ContainerContents<'_>,
) -> Result<WriteReport, ContainerError> {
    let model = contents.model;
    let coefficient_kernels = model.coefficient_kernels();
    let basis_kernels = model.basis_kernels();
    let (_, rank, dim) = model.basis().dim();
    let to_u32 = |d: [usize; 3]| d.map(|n| n as u32);
    let coefficients = GridArray::new(
        to_u32(coefficient_kernels.nodes()),
        rank,
        model.coefficients().iter().copied().collect(),
    )?;
    let basis = GridArray::new(
        to_u32(basis_kernels.nodes()),
        rank * dim,
        model.basis().iter().copied().collect(),
    )?;
    let validity = GridArray::new(
        to_u32(contents.grid),
        1,
        contents
            .valid
            .iter()
            .map(|&v| if v { 1.0 } else { 0.0 })
            .collect(),
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
    let container = Container {
        attributes,
        kernels,
        arrays: vec![
            (
                MBD_COEFFICIENTS.to_string(),
                coefficients,
                encoding,
                ArrayLayout::Volume,
            ),
            (MBD_BASIS.to_string(), basis, encoding, ArrayLayout::Atlas),
            (
                VALIDITY.to_string(),
                validity,
                Encoding::Unorm8,
                ArrayLayout::Volume,
            ),
        ],
    };
    Ok(container.write(folder)?)
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
