//! Kept volumes: the traced transfer volume and the baselines' reconstructions, written beside
//! the MBD container so that later tools (exports, renders, the viewer) can light the
//! reference and compare against it without tracing again.

use std::collections::BTreeMap;
use std::path::Path;

use glam::Vec3;
use ndarray::Array2;
use prt_core::{Aabb, GridField};
use prt_texture::container::{ArrayLayout, Container, GridArray, LoadedContainer, WriteReport};
use prt_texture::{Encoding, Limits, TextureError};
use prt_trace::TRANSFER_DIM;
use serde_json::json;

use crate::Bake;
use crate::container::{ContainerError, VALIDITY};

/// Value of the `model` attribute of a kept-volumes container.
pub const KEPT_VOLUMES: &str = "kept transfer volumes";
/// Name of the traced transfer volume among the kept volumes.
pub const REFERENCE: &str = "reference";
/// Channels per written array: a 324-D volume is split into this many-channel parts so that
/// each part's 3D texture (`ceil(36 / 4) = 9` slabs along z) stays within texture-depth limits.
const PART_CHANNELS: usize = 36;
const PARTS: usize = TRANSFER_DIM / PART_CHANNELS;

/// The volumes [`read_volumes`] gives back.
#[derive(Debug, Clone)]
pub struct KeptVolumes {
    /// Voxels along x, y, z.
    pub grid: [usize; 3],
    /// The box the voxels tile.
    pub bounds: Aabb,
    /// Per voxel: `false` inside geometry or outside the scene.
    pub valid: Vec<bool>,
    /// `(name, 324-D field)`: [`REFERENCE`] first, then the baselines (`"bpca"`, `"cpca"`) the
    /// bake computed.
    pub volumes: Vec<(String, GridField)>,
}

impl KeptVolumes {
    /// The volume named `name`, if kept.
    pub fn get(&self, name: &str) -> Option<&GridField> {
        self.volumes.iter().find(|(n, _)| n == name).map(|(_, f)| f)
    }
}

/// Bytes [`write_volumes`] writes for `bake` with `encoding` (texel payloads, without headers):
/// what a caller checks before deciding to keep the volumes.
pub fn kept_volume_bytes(bake: &Bake, encoding: Encoding) -> u64 {
    let voxels = bake.volume.field.num_voxels() as u64;
    let methods = 1 + bake.baselines.len() as u64;
    let texel_bytes = encoding.rgba_format().bytes_per_texel() as u64;
    methods * voxels * TRANSFER_DIM as u64 / 4 * texel_bytes
}

/// Writes the traced volume (as [`REFERENCE`]) and every baseline's reconstruction (under its
/// method's lower-case name) into `folder` as a prt container: each 324-D volume as nine
/// 36-channel 3D textures `NAME.K` (K = 0..8, channels `36K..36K+35`), plus the validity mask.
/// Atomic per file, manifest last.
pub fn write_volumes(
    folder: &Path,
    bake: &Bake,
    encoding: Encoding,
) -> Result<WriteReport, ContainerError> {
    let field = &bake.volume.field;
    let dims = field.dims().map(|n| n as u32);
    let mut arrays = Vec::new();
    let mut names = vec![REFERENCE.to_string()];
    push_parts(&mut arrays, REFERENCE, field, dims, encoding)?;
    for baseline in &bake.baselines {
        let name = baseline.method.name().to_lowercase();
        let reconstruction = baseline
            .model
            .reconstruct()
            .map_err(ContainerError::Model)?;
        push_parts(&mut arrays, &name, &reconstruction, dims, encoding)?;
        names.push(name);
    }
    let validity = bake
        .volume
        .valid
        .iter()
        .map(|&v| if v { 1.0 } else { 0.0 })
        .collect();
    arrays.push((
        VALIDITY.to_string(),
        GridArray::new(dims, 1, validity)?,
        Encoding::Unorm8,
        ArrayLayout::Volume,
    ));
    let bounds = field.bounds();
    let mut attributes = BTreeMap::new();
    attributes.insert("model".into(), json!(KEPT_VOLUMES));
    attributes.insert("volumes".into(), json!(names));
    attributes.insert("bounds_min".into(), json!(bounds.min.to_array()));
    attributes.insert("bounds_max".into(), json!(bounds.max.to_array()));
    attributes.insert(
        "vector_layout".into(),
        json!("[direct 9x9 | indirect R 9x9 | G 9x9 | B 9x9], each row-major T[i*9+j], i = incident-radiance SH, j = sky SH; array NAME.K holds channels 36K..36K+35"),
    );
    let container = Container {
        attributes,
        kernels: BTreeMap::new(),
        arrays,
        ..Container::default()
    };
    Ok(container.write(folder)?)
}

fn push_parts(
    arrays: &mut Vec<(String, GridArray, Encoding, ArrayLayout)>,
    name: &str,
    field: &GridField,
    dims: [u32; 3],
    encoding: Encoding,
) -> Result<(), ContainerError> {
    if field.dim() != TRANSFER_DIM {
        return Err(ContainerError::Inconsistent(format!(
            "volume {name} has {} channels, not {TRANSFER_DIM}",
            field.dim()
        )));
    }
    for part in 0..PARTS {
        let channels = part * PART_CHANNELS..(part + 1) * PART_CHANNELS;
        let mut data = Vec::with_capacity(field.num_voxels() * PART_CHANNELS);
        for v in 0..field.num_voxels() {
            data.extend_from_slice(&field.voxel(v)[channels.clone()]);
        }
        arrays.push((
            format!("{name}.{part}"),
            GridArray::new(dims, PART_CHANNELS, data)?,
            encoding,
            ArrayLayout::Volume,
        ));
    }
    Ok(())
}

/// Reads what [`write_volumes`] wrote, checking every file against `limits` and the arrays
/// against each other and the attributes.
pub fn read_volumes(folder: &Path, limits: &Limits) -> Result<KeptVolumes, ContainerError> {
    let loaded = LoadedContainer::read(folder, limits)?;
    let attributes = &loaded.manifest.attributes;
    let model = attributes.get("model").and_then(|v| v.as_str());
    if model != Some(KEPT_VOLUMES) {
        return Err(ContainerError::Inconsistent(format!(
            "the model attribute is {model:?}, not {KEPT_VOLUMES:?}"
        )));
    }
    let corner = |key: &'static str| -> Result<Vec3, ContainerError> {
        let values: Option<Vec<f32>> = attributes
            .get(key)
            .and_then(|v| v.as_array())
            .filter(|a| a.len() == 3)
            .and_then(|a| a.iter().map(|x| x.as_f64().map(|x| x as f32)).collect());
        match values {
            Some(v) if v.iter().all(|x| x.is_finite()) => Ok(Vec3::new(v[0], v[1], v[2])),
            _ => Err(ContainerError::Inconsistent(format!(
                "attribute {key} is not three finite numbers"
            ))),
        }
    };
    let bounds = Aabb {
        min: corner("bounds_min")?,
        max: corner("bounds_max")?,
    };
    if !(bounds.min.cmplt(bounds.max).all()) {
        return Err(ContainerError::Inconsistent(format!(
            "bounds {bounds:?} are empty or inverted"
        )));
    }
    let validity = loaded.array(VALIDITY).ok_or(ContainerError::Missing {
        kind: "array",
        name: VALIDITY,
    })?;
    if validity.channels != 1 {
        return Err(ContainerError::Inconsistent(format!(
            "validity has {} channels, not 1",
            validity.channels
        )));
    }
    let grid = validity.dims.map(|d| d as usize);
    let names: Vec<String> = attributes
        .get("volumes")
        .and_then(|v| v.as_array())
        .map(|a| {
            a.iter()
                .filter_map(|n| n.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    if names.first().map(String::as_str) != Some(REFERENCE) {
        return Err(ContainerError::Inconsistent(format!(
            "the volumes attribute {names:?} does not start with {REFERENCE:?}"
        )));
    }
    let voxels = validity.nodes();
    // The manifest's list is checked against the arrays before anything is allocated: each name
    // once, each with all its parts, and the volumes together within the reader's limits.
    for (i, name) in names.iter().enumerate() {
        if names[..i].contains(name) {
            return Err(ContainerError::Inconsistent(format!(
                "volume {name} is listed twice"
            )));
        }
        for part in 0..PARTS {
            let part_name = format!("{name}.{part}");
            if loaded.array(&part_name).is_none() {
                return Err(ContainerError::Inconsistent(format!(
                    "array {part_name} is missing"
                )));
            }
        }
    }
    let bytes = (names.len() as u64)
        .saturating_mul(voxels as u64)
        .saturating_mul((TRANSFER_DIM * std::mem::size_of::<f32>()) as u64);
    if bytes > limits.max_bytes {
        return Err(TextureError::TooLarge {
            what: "kept volumes in memory (bytes)",
            value: bytes,
            limit: limits.max_bytes,
        }
        .into());
    }
    let mut volumes = Vec::with_capacity(names.len());
    for name in names {
        let mut data = Array2::<f32>::zeros((voxels, TRANSFER_DIM));
        for part in 0..PARTS {
            let part_name = format!("{name}.{part}");
            let array = loaded.array(&part_name).ok_or_else(|| {
                ContainerError::Inconsistent(format!("array {part_name} is missing"))
            })?;
            if array.dims != validity.dims || array.channels != PART_CHANNELS {
                return Err(ContainerError::Inconsistent(format!(
                    "array {part_name} is {:?} × {} channels, not {:?} × {PART_CHANNELS}",
                    array.dims, array.channels, validity.dims
                )));
            }
            for (v, values) in array.data.chunks_exact(PART_CHANNELS).enumerate() {
                let start = part * PART_CHANNELS;
                data.row_mut(v)
                    .as_slice_mut()
                    .expect("rows of a standard-layout array are contiguous")
                    [start..start + PART_CHANNELS]
                    .copy_from_slice(values);
            }
        }
        let field = GridField::from_data(grid, bounds, data)
            .map_err(|e| ContainerError::Inconsistent(format!("volume {name}: {e}")))?;
        volumes.push((name, field));
    }
    Ok(KeptVolumes {
        grid,
        bounds,
        valid: validity.data.iter().map(|&v| v > 0.5).collect(),
        volumes,
    })
}
