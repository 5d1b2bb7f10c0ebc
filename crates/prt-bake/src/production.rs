//! The production configuration of Moving Basis Decomposition (Silvennoinen & Sloan 2021,
//! §5.1): linear-SH irradiance lit by a given sky, a rank-3 hybrid model whose basis lives on a
//! 2D grid over the terrain and whose coefficients live in a 3D volume, written as 8-bit
//! textures at node resolution (so hardware filtering computes the hat sums).

use std::collections::BTreeMap;
use std::f32::consts::PI;
use std::path::Path;

use glam::Vec3;
use ndarray::{Array2, Array3};
use prt_core::{Aabb, GridField, Progress, SpatialKernels};
use prt_kernels::{HatGrid, HybridKernels, KernelError};
use prt_mbd::{MbdError, MbdModel, SolveReport, SolverOptions};
use prt_sphere::Sky;
use prt_texture::container::{
    ArrayLayout, Container, GridArray, LoadedContainer, MBD_BASIS, MBD_COEFFICIENTS, Manifest,
    WriteReport,
};
use prt_texture::{Encoding, Limits};
use prt_trace::TRANSFER_DIM;
use prt_trace::lit::incident_radiance;
use serde_json::json;
use thiserror::Error;

use crate::container::{ContainerError, coefficient_encoding, kernel_description};

/// Values per voxel of the irradiance target: L0 and the three L1 coefficients of R, G and B.
pub const IRRADIANCE_L1_DIM: usize = 12;
/// Value of the `model` attribute of a production container.
pub const PRODUCTION_MODEL: &str = "moving basis decomposition, hybrid (2D basis, 3D coefficients)";
/// Kernel kind of a trilinear hat grid (the coefficients).
const HAT: &str = "hat";
/// Kernel kind of a 2D hat grid over XZ, constant along Y (the basis, [`HybridKernels`]).
const HAT_XZ: &str = "hat_xz";
/// Clamped-cosine convolution of bands 0 and 1 (Ramamoorthi & Hanrahan 2001): π and 2π/3.
const CLAMPED_COSINE_L1: [f32; 4] = [PI, 2.0 * PI / 3.0, 2.0 * PI / 3.0, 2.0 * PI / 3.0];

/// The production model: coefficients on a 3D hat grid, basis on a 2D hat grid over XZ.
pub type ProductionModel = MbdModel<HatGrid, HybridKernels>;

/// What can go wrong preparing, fitting or storing the production configuration.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ProductionError {
    /// An input does not have the shape or values the step needs.
    #[error("{what}: {why}")]
    InvalidInput {
        /// Which input.
        what: &'static str,
        /// What is wrong with it.
        why: String,
    },
    /// A grid of [`ProductionConfig`] is not a valid hat grid on the field's box.
    #[error("invalid {which} grid")]
    Kernels {
        /// `"coefficient"` or `"basis"`.
        which: &'static str,
        /// Why.
        #[source]
        source: KernelError,
    },
    /// The MBD solve failed or was cancelled.
    #[error("MBD solve failed")]
    Mbd(#[source] MbdError),
    /// The container could not be written or read.
    #[error(transparent)]
    Container(#[from] ContainerError),
}

/// The linear-SH irradiance (`IRRADIANCE_L1_DIM` = 12 values per voxel) of a 324-D transfer
/// volume lit by `sky`: the incident radiance's SH bands 0 and 1
/// ([`prt_trace::lit::incident_radiance`]) convolved with the clamped cosine (× π for L0, × 2π/3
/// for L1), so that `E_c(n) = Σ_k e[4c + k] Y_k(n)` is the irradiance on a surface of normal `n`
/// (divide by π for the exit radiance of a white Lambertian surface). Layout `d = 4c + k`:
/// colour c = R, G, B major, then k = L0, L1 m = −1 (y), m = 0 (z), m = +1 (x) in prt's SH
/// convention: one RGBA texel per colour, the order of
/// `prt_export::layout::ShL1Layout::PerChannel`.
///
/// # Errors
/// [`ProductionError::InvalidInput`] if the field is not 324-D.
pub fn irradiance_l1(transfer: &GridField, sky: &Sky) -> Result<GridField, ProductionError> {
    if transfer.dim() != TRANSFER_DIM {
        return Err(ProductionError::InvalidInput {
            what: "transfer volume",
            why: format!("{} values per voxel, not {TRANSFER_DIM}", transfer.dim()),
        });
    }
    let mut data = Array2::<f32>::zeros((transfer.num_voxels(), IRRADIANCE_L1_DIM));
    for (v, mut row) in data.rows_mut().into_iter().enumerate() {
        let radiance = incident_radiance(transfer.voxel(v), sky);
        for (c, l) in radiance.iter().enumerate() {
            for k in 0..4 {
                row[4 * c + k] = CLAMPED_COSINE_L1[k] * l[k];
            }
        }
    }
    GridField::from_data(transfer.dims(), transfer.bounds(), data).map_err(|e| {
        ProductionError::InvalidInput {
            what: "irradiance",
            why: e.to_string(),
        }
    })
}

/// `field` with every invalid voxel (inside geometry, under the terrain) replaced by the mean
/// of its already-known face neighbours, grown outwards from the valid voxels one layer per
/// pass. Invalid voxels hold zeros that no renderer samples; filled, they cost a low-rank fit
/// nothing, and the model does not drag dark values across surfaces.
///
/// # Errors
/// [`ProductionError::InvalidInput`] if `valid` does not have one entry per voxel or no voxel is
/// valid.
pub fn fill_invalid(field: &GridField, valid: &[bool]) -> Result<GridField, ProductionError> {
    let voxels = field.num_voxels();
    if valid.len() != voxels {
        return Err(ProductionError::InvalidInput {
            what: "validity mask",
            why: format!("{} entries for {voxels} voxels", valid.len()),
        });
    }
    if !valid.contains(&true) {
        return Err(ProductionError::InvalidInput {
            what: "validity mask",
            why: "no valid voxel to fill from".into(),
        });
    }
    let dims = field.dims();
    let d = field.dim();
    let mut data = field.data().to_owned();
    let mut known = valid.to_vec();
    let mut layer: Vec<(usize, Vec<f32>)> = Vec::new();
    loop {
        layer.clear();
        for v in (0..voxels).filter(|&v| !known[v]) {
            let [x, y, z] = field.coords(v);
            let mut sum = vec![0.0f64; d];
            let mut count = 0u32;
            for (axis, coordinate) in [x, y, z].into_iter().enumerate() {
                for step in [-1isize, 1] {
                    let Some(c) = coordinate
                        .checked_add_signed(step)
                        .filter(|&c| c < dims[axis])
                    else {
                        continue;
                    };
                    let mut n = [x, y, z];
                    n[axis] = c;
                    let u = field.index(n[0], n[1], n[2]);
                    if known[u] {
                        count += 1;
                        for (s, &value) in sum.iter_mut().zip(data.row(u)) {
                            *s += f64::from(value);
                        }
                    }
                }
            }
            if count > 0 {
                let mean = sum.iter().map(|s| (s / f64::from(count)) as f32).collect();
                layer.push((v, mean));
            }
        }
        if layer.is_empty() {
            break;
        }
        // A whole layer is decided from the previous one, so the result does not depend on the
        // voxel order within a pass.
        for (v, mean) in &layer {
            data.row_mut(*v)
                .iter_mut()
                .zip(mean)
                .for_each(|(o, &m)| *o = m);
            known[*v] = true;
        }
    }
    GridField::from_data(dims, field.bounds(), data).map_err(|e| ProductionError::InvalidInput {
        what: "filled field",
        why: e.to_string(),
    })
}

/// The knobs of [`fit_production`].
#[derive(Debug, Clone, PartialEq)]
pub struct ProductionConfig {
    /// Moving basis vectors per point, L (the paper's production rank is 3).
    pub rank: usize,
    /// Basis nodes along x and z of the 2D grid over the terrain (at least 2 each).
    pub basis_nodes: [usize; 2],
    /// Coefficient nodes along x, y, z of the 3D volume (at least 1 each; fewer than the voxels
    /// of the target is what brings the storage under one byte per coefficient per voxel).
    pub coefficient_nodes: [usize; 3],
    /// The stochastic solver's options.
    pub solver: SolverOptions,
}

impl ProductionConfig {
    /// The production densities for a target of `dims` voxels: rank 3, coefficients at half
    /// the voxel resolution along x and z and full resolution along y (one RGBA8 texel per four
    /// voxel columns and layer: 1 byte per voxel), basis nodes every 8 voxels along x and z.
    pub fn for_grid(dims: [usize; 3]) -> Self {
        let half = |n: usize| n.div_ceil(2).max(2);
        let every_8 = |n: usize| (n.saturating_sub(1) / 8 + 1).max(1) + 1;
        Self {
            rank: 3,
            basis_nodes: [every_8(dims[0]), every_8(dims[2])],
            coefficient_nodes: [half(dims[0]), dims[1], half(dims[2])],
            solver: SolverOptions::default(),
        }
    }
}

/// What [`fit_production`] returns.
#[derive(Debug, Clone)]
pub struct ProductionFit {
    /// The fitted model.
    pub model: ProductionModel,
    /// The solver's history.
    pub report: SolveReport,
}

/// The coefficient volume and the 2D basis grid of `config` over the box of `field`'s voxel
/// centres (where the field's own trilinear interpolation lives).
pub fn production_kernels(
    field: &GridField,
    config: &ProductionConfig,
) -> Result<(HatGrid, HybridKernels), ProductionError> {
    let domain = prt_mbd::expert::voxel_centre_box(field);
    let [nx, nz] = config.basis_nodes;
    let basis = HybridKernels::new(nx, nz, domain).map_err(|source| ProductionError::Kernels {
        which: "basis",
        source,
    })?;
    let coefficients = basis
        .coefficient_grid(config.coefficient_nodes)
        .map_err(|source| ProductionError::Kernels {
            which: "coefficient",
            source,
        })?;
    Ok((coefficients, basis))
}

/// Fits the production model to `field` (e.g. [`irradiance_l1`] of a bake, invalid voxels
/// [filled](fill_invalid)) with the paper's solver over the kernels of [`production_kernels`].
/// Deterministic for the solver's seed on any thread count.
///
/// # Errors
/// [`ProductionError::Kernels`] for grids that are not valid hat grids (a basis axis with fewer
/// than 2 nodes, a flat box), [`ProductionError::Mbd`] for what the solver refuses (rank 0 or
/// above D, non-finite values, bad options) or cancellation.
pub fn fit_production(
    field: &GridField,
    config: &ProductionConfig,
    progress: &dyn Progress,
) -> Result<ProductionFit, ProductionError> {
    let (coefficients, basis) = production_kernels(field, config)?;
    let (model, report) = prt_mbd::expert::solve(
        field,
        coefficients,
        basis,
        config.rank,
        &config.solver,
        progress,
    )
    .map_err(ProductionError::Mbd)?;
    Ok(ProductionFit { model, report })
}

/// What [`write_production`] stores: the model and a little provenance.
#[derive(Debug, Clone, Copy)]
pub struct ProductionContents<'a> {
    /// The model (its vectors in the layout of [`irradiance_l1`]).
    pub model: &'a ProductionModel,
    /// Voxels of the target grid along x, y, z (the `grid` attribute; bytes per voxel count
    /// these).
    pub grid: [usize; 3],
    /// The scene's name (the `scene` attribute).
    pub scene: &'a str,
    /// The sky the target was lit by (the `sky` attribute, 27 SH coefficients).
    pub sky: &'a Sky,
    /// Encoding of both textures (the production one is [`Encoding::Unorm8`]).
    pub encoding: Encoding,
}

/// A production container read back.
#[derive(Debug, Clone, PartialEq)]
pub struct ProductionContainer {
    /// The model, evaluating the L1 irradiance anywhere in the box ([`prt_core::FieldModel`]).
    pub model: ProductionModel,
    /// Voxels of the target grid along x, y, z.
    pub grid: [usize; 3],
    /// The sky the target was lit by.
    pub sky: Sky,
    /// Encoding of the textures.
    pub encoding: Encoding,
    /// The validated manifest with every attribute.
    pub manifest: Manifest,
}

impl ProductionContainer {
    /// Bytes of texel data (the two textures' level 0, headers and manifest excluded).
    pub fn texel_bytes(&self) -> u64 {
        texel_bytes(&self.manifest)
    }
}

/// Bytes of texel data of every array of `manifest`: nodes × texels per node × texel size.
pub fn texel_bytes(manifest: &Manifest) -> u64 {
    manifest
        .arrays
        .iter()
        .map(|a| {
            let nodes: u64 = a.dims.iter().map(|&n| u64::from(n)).product();
            let texel = a.texture_format().bytes_per_texel() as u64;
            nodes * a.groups() as u64 * texel
        })
        .sum()
}

/// Writes the production container into `folder` (created if missing), each file atomically
/// and the manifest last:
///
/// * `coefficients.ktx2`: the coefficient volume, one texel per node (`L` channels packed in
///   RGBA, group `g` in depth slices `g·nz .. (g+1)·nz`); for rank 3 one RGBA texture whose
///   alpha is unused;
/// * `basis.ktx2`: the 2D basis grid as a 3D texture of `nx × nz × 3L` texels, depth slice
///   `3l + c` holding colour `c` of basis vector `l` as (L0, L1y, L1z, L1x);
/// * `manifest.json`: kernels, per-channel decode ranges (`value = bias + scale · texel`),
///   rank, layout, scene, sky, grid.
///
/// Returns what was written (bytes included).
///
/// # Errors
/// [`ProductionError::InvalidInput`] for a model whose vectors are not [`IRRADIANCE_L1_DIM`]
/// long; [`ContainerError::Texture`] for non-finite values and I/O errors.
pub fn write_production(
    folder: &Path,
    contents: &ProductionContents<'_>,
) -> Result<WriteReport, ProductionError> {
    let model = contents.model;
    let (_, rank, dim) = model.basis().dim();
    if dim != IRRADIANCE_L1_DIM {
        return Err(ProductionError::InvalidInput {
            what: "production model",
            why: format!("vectors of {dim} values, not {IRRADIANCE_L1_DIM}"),
        });
    }
    let coefficient_kernels = model.coefficient_kernels();
    let basis_kernels = model.basis_kernels();
    let [nx, _, nz] = basis_kernels.grid().nodes();
    let texture_error = |e| ProductionError::Container(ContainerError::Texture(e));
    let to_u32 = |d: [usize; 3]| d.map(|n| n as u32);
    let coefficients = GridArray::new(
        to_u32(coefficient_kernels.nodes()),
        rank,
        model.coefficients().iter().copied().collect(),
    )
    .map_err(texture_error)?;
    // The basis nodes as an nx × nz image (node i + nx·k is texel (i, k)): each RGBA group then
    // becomes one depth slice that bilinear filtering reads without crossing into another.
    let basis = GridArray::new(
        to_u32([nx, nz, 1]),
        rank * dim,
        model.basis().iter().copied().collect(),
    )
    .map_err(texture_error)?;
    let mut attributes = BTreeMap::new();
    attributes.insert("model".into(), json!(PRODUCTION_MODEL));
    attributes.insert("scene".into(), json!(contents.scene));
    attributes.insert("rank".into(), json!(rank));
    attributes.insert("dimension".into(), json!(dim));
    attributes.insert("grid".into(), json!(contents.grid));
    attributes.insert(
        "vector_layout".into(),
        json!("irradiance L1 SH, d = 4c + k: colour c = R, G, B; k = L0, L1 y, L1 z, L1 x (radiance SH x clamped cosine: pi, 2pi/3)"),
    );
    attributes.insert(
        "basis_channel_order".into(),
        json!("channel = l * dimension + d; the basis texture is nx x nz x (3 rank), slice 3l + c = colour c of vector l"),
    );
    attributes.insert("sky".into(), json!(contents.sky.sh));
    let mut kernels = BTreeMap::new();
    kernels.insert(
        MBD_COEFFICIENTS.to_string(),
        kernel_description(
            HAT,
            coefficient_kernels.nodes(),
            coefficient_kernels.domain(),
        ),
    );
    kernels.insert(
        MBD_BASIS.to_string(),
        kernel_description(HAT_XZ, [nx, 1, nz], basis_kernels.domain()),
    );
    let container = Container {
        attributes,
        kernels,
        arrays: vec![
            (
                MBD_COEFFICIENTS.to_string(),
                coefficients,
                contents.encoding,
                ArrayLayout::Volume,
            ),
            (
                MBD_BASIS.to_string(),
                basis,
                contents.encoding,
                ArrayLayout::Volume,
            ),
        ],
        ..Container::default()
    };
    container
        .write(folder)
        .map_err(|e| ProductionError::Container(e.into()))
}

/// Reads a container written by [`write_production`], checking every file against `limits` and
/// the arrays against the kernels and attributes.
///
/// # Errors
/// [`ContainerError`]s (inside [`ProductionError::Container`]): unreadable, malformed or
/// oversized files, a missing array, kernel family or attribute, arrays that disagree with
/// their kernels or with each other, another kind of container.
pub fn read_production(
    folder: &Path,
    limits: &Limits,
) -> Result<ProductionContainer, ProductionError> {
    let loaded = LoadedContainer::read(folder, limits).map_err(ContainerError::from)?;
    Ok(from_loaded(loaded)?)
}

fn from_loaded(loaded: LoadedContainer) -> Result<ProductionContainer, ContainerError> {
    let manifest = &loaded.manifest;
    let inconsistent = |why: String| ContainerError::Inconsistent(why);
    let model_kind = manifest.attributes.get("model").and_then(|v| v.as_str());
    if model_kind != Some(PRODUCTION_MODEL) {
        return Err(inconsistent(format!(
            "the model attribute is {model_kind:?}, not {PRODUCTION_MODEL:?}"
        )));
    }
    let array = |name: &'static str| {
        loaded.array(name).ok_or(ContainerError::Missing {
            kind: "array",
            name,
        })
    };
    let (coefficients, basis) = (array(MBD_COEFFICIENTS)?, array(MBD_BASIS)?);
    let coefficient_domain = kernel_domain(manifest, MBD_COEFFICIENTS, HAT, coefficients.dims)?;
    let [nx, nz, one] = basis.dims;
    if one != 1 {
        return Err(inconsistent(format!(
            "the basis array is {:?}, not an nx x nz image",
            basis.dims
        )));
    }
    let basis_domain = kernel_domain(manifest, MBD_BASIS, HAT_XZ, [nx, 1, nz])?;
    let to_usize = |d: [u32; 3]| d.map(|n| n as usize);
    let coefficient_kernels = HatGrid::new(to_usize(coefficients.dims), coefficient_domain)
        .map_err(|source| ContainerError::Kernels {
            which: MBD_COEFFICIENTS,
            source,
        })?;
    let basis_kernels =
        HybridKernels::new(nx as usize, nz as usize, basis_domain).map_err(|source| {
            ContainerError::Kernels {
                which: MBD_BASIS,
                source,
            }
        })?;
    let rank = coefficients.channels;
    if basis.channels != rank * IRRADIANCE_L1_DIM {
        return Err(inconsistent(format!(
            "{} basis channels for rank {rank} and {IRRADIANCE_L1_DIM}-D vectors",
            basis.channels
        )));
    }
    for (key, want) in [("rank", rank), ("dimension", IRRADIANCE_L1_DIM)] {
        let stated = manifest.attributes.get(key).and_then(|v| v.as_u64());
        if stated != Some(want as u64) {
            return Err(inconsistent(format!(
                "the {key} attribute is {stated:?}, the arrays say {want}"
            )));
        }
    }
    let grid = numbers::<3>(manifest, "grid")?;
    if grid
        .iter()
        .any(|&n| n < 1.0 || n.fract() != 0.0 || n > f64::from(u32::MAX))
    {
        return Err(inconsistent(format!(
            "the grid attribute {grid:?} is not a voxel count"
        )));
    }
    let grid = grid.map(|n| n as usize);
    let sky = numbers::<27>(manifest, "sky")?;
    let sky = Sky::from_coefficients(std::array::from_fn(|c| {
        std::array::from_fn(|j| sky[9 * c + j] as f32)
    }))
    .map_err(|e| inconsistent(format!("sky: {e}")))?;
    let encoding = coefficient_encoding(manifest)?;
    let shape_error = |e: ndarray::ShapeError| inconsistent(e.to_string());
    let coefficients =
        Array2::from_shape_vec((coefficients.nodes(), rank), coefficients.data.clone())
            .map_err(shape_error)?;
    let basis =
        Array3::from_shape_vec((basis.nodes(), rank, IRRADIANCE_L1_DIM), basis.data.clone())
            .map_err(shape_error)?;
    let model = MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)
        .map_err(ContainerError::Model)?;
    Ok(ProductionContainer {
        model,
        grid,
        sky,
        encoding,
        manifest: loaded.manifest,
    })
}

/// The domain of kernel family `name`, which must be of `kind` with `nodes` nodes.
fn kernel_domain(
    manifest: &Manifest,
    name: &'static str,
    kind: &str,
    nodes: [u32; 3],
) -> Result<Aabb, ContainerError> {
    let description = manifest.kernels.get(name).ok_or(ContainerError::Missing {
        kind: "kernels",
        name,
    })?;
    if description.kind != kind || description.nodes != nodes {
        return Err(ContainerError::Inconsistent(format!(
            "{name} kernels are {:?} with {:?} nodes, the array needs {kind:?} with {nodes:?}",
            description.kind, description.nodes
        )));
    }
    // Not `Aabb::new`, which would silently swap corners given in the wrong order.
    Ok(Aabb {
        min: Vec3::from_array(description.domain_min),
        max: Vec3::from_array(description.domain_max),
    })
}

/// Attribute `key` of `manifest`: `N` numbers, possibly nested in arrays (row-major).
fn numbers<const N: usize>(
    manifest: &Manifest,
    key: &'static str,
) -> Result<[f64; N], ContainerError> {
    fn flatten(value: &serde_json::Value, out: &mut Vec<f64>) -> bool {
        match value {
            serde_json::Value::Array(items) => items.iter().all(|item| flatten(item, out)),
            serde_json::Value::Number(n) => n.as_f64().map(|x| out.push(x)).is_some(),
            _ => false,
        }
    }
    let value = manifest
        .attributes
        .get(key)
        .ok_or(ContainerError::Missing {
            kind: "attribute",
            name: key,
        })?;
    let mut values = Vec::with_capacity(N);
    if !flatten(value, &mut values) || values.len() != N {
        return Err(ContainerError::Inconsistent(format!(
            "the {key} attribute is not {N} numbers"
        )));
    }
    let mut out = [0.0; N];
    out.copy_from_slice(&values);
    Ok(out)
}
