//! `prt inspect FILE`: what a KTX2 / EXR / HDR file or a prt container manifest holds.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use prt_bake::container::MBD_MODEL;
use prt_bake::container::read_container;
use prt_core::{FieldModel, SpatialKernels};
use prt_kernels::HatGrid;
use prt_texture::container::{MANIFEST_FILE, Manifest};
use prt_texture::{Ktx2Texture, Limits};

/// Options of `prt inspect`.
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// A .ktx2, .exr or .hdr file, a container manifest (.json), or a container folder.
    pub file: PathBuf,
}

pub fn run(args: &InspectArgs) -> Result<()> {
    let path = &args.file;
    if !path.exists() {
        bail!("{} does not exist", path.display());
    }
    let limits = Limits::default();
    if path.is_dir() {
        return inspect_manifest(&path.join(MANIFEST_FILE), &limits);
    }
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    match extension.as_str() {
        "ktx2" => inspect_ktx2(path, &limits),
        "exr" => {
            let layers = prt_texture::exr_io::read_exr(path, &limits)
                .with_context(|| format!("cannot read {}", path.display()))?;
            println!("EXR {}: {} layer(s)", path.display(), layers.len());
            for layer in &layers {
                let (min, max) = range(&layer.data);
                println!(
                    "  {}: {} x {}, {} channels, values {min:.4e} .. {max:.4e}",
                    layer.name.as_deref().unwrap_or("(unnamed)"),
                    layer.width,
                    layer.height,
                    layer.channels
                );
            }
            Ok(())
        }
        "hdr" | "pic" => {
            let image = prt_texture::hdr::read_hdr(path, &limits)
                .with_context(|| format!("cannot read {}", path.display()))?;
            let (min, max) = range(&image.data);
            println!(
                "Radiance HDR {}: {} x {} RGB, values {min:.4e} .. {max:.4e}",
                path.display(),
                image.width,
                image.height
            );
            Ok(())
        }
        "json" => inspect_manifest(path, &limits),
        _ => bail!(
            "{}: unknown file type (expected .ktx2, .exr, .hdr or a manifest .json)",
            path.display()
        ),
    }
}

fn range(values: &[f32]) -> (f32, f32) {
    values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        })
}

fn inspect_ktx2(path: &Path, limits: &Limits) -> Result<()> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let texture = Ktx2Texture::from_bytes(&bytes, limits)
        .with_context(|| format!("{} is not a valid KTX2 file", path.display()))?;
    let s = texture.shape();
    println!("KTX2 {}: {} bytes", path.display(), bytes.len());
    println!("  format {:?}", texture.format());
    println!(
        "  {} x {} x {}, {} layer(s), {} face(s), {} mip level(s)",
        s.width,
        s.height.max(1),
        s.depth.max(1),
        s.layers.max(1),
        s.faces,
        texture.levels().len()
    );
    for (key, value) in texture.key_values() {
        let text = String::from_utf8_lossy(value.strip_suffix(&[0]).unwrap_or(value));
        let shown: String = text.chars().take(160).collect();
        let more = if text.chars().count() > 160 {
            " ..."
        } else {
            ""
        };
        println!("  key {key}: {shown}{more}");
    }
    Ok(())
}

fn inspect_manifest(path: &Path, limits: &Limits) -> Result<()> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let manifest = Manifest::from_json(&bytes, limits)
        .with_context(|| format!("{} is not a prt container manifest", path.display()))?;
    println!(
        "prt container {} (format {} version {})",
        path.display(),
        manifest.format,
        manifest.version
    );
    for (key, value) in &manifest.attributes {
        println!("  {key}: {value}");
    }
    for (name, k) in &manifest.kernels {
        println!(
            "  kernels {name}: {} with {:?} nodes over {:?} .. {:?}",
            k.kind, k.nodes, k.domain_min, k.domain_max
        );
    }
    for a in &manifest.arrays {
        let tiles = a
            .tiles
            .map(|[x, y, z]| format!(" ({x} x {y} x {z} tiles)"))
            .or_else(|| {
                a.bricks.as_ref().map(|b| {
                    format!(
                        " ({} of {:?} bricks of {} cells live, indirection {} bytes in {})",
                        b.live, b.grid, b.size, b.indirection_bytes, b.indirection
                    )
                })
            })
            .unwrap_or_default();
        println!(
            "  array {}: {:?} nodes x {} channels, {:?}, {:?} layout{tiles}, {} bytes in {}",
            a.name, a.dims, a.channels, a.encoding, a.layout, a.bytes, a.file
        );
    }
    let is_mbd = manifest.attributes.get("model").and_then(|v| v.as_str()) == Some(MBD_MODEL);
    if is_mbd {
        let folder = path.parent().unwrap_or(Path::new("."));
        inspect_model(folder, limits)?;
    }
    Ok(())
}

/// Reads an MBD container's model back and prints its shape.
fn inspect_model(folder: &Path, limits: &Limits) -> Result<()> {
    let container = read_container(folder, limits)
        .with_context(|| format!("cannot read the MBD model in {}", folder.display()))?;
    let model = &container.model;
    let kernels = |k: &HatGrid| {
        let [x, y, z] = k.nodes();
        let domain = k.domain();
        format!(
            "hat grid {x} x {y} x {z} over {:?} .. {:?}",
            domain.min.to_array(),
            domain.max.to_array()
        )
    };
    let valid = container.valid.iter().filter(|v| **v).count();
    println!(
        "  model: MBD rank {}, dimension {}, {} stored scalars, stored as {:?}",
        model.rank(),
        model.dim(),
        model.stored_scalars(),
        container.encoding
    );
    println!(
        "  coefficient kernels: {}",
        kernels(model.coefficient_kernels())
    );
    println!("  basis kernels: {}", kernels(model.basis_kernels()));
    println!(
        "  validity: {valid} valid voxels of {} ({:?})",
        container.valid.len(),
        container.grid
    );
    Ok(())
}
