//! `--sky` and `--rotate`: the sky that lights a bake, for every command that lights one
//! (`prt export`; later `render`, `view`).

use std::path::Path;

use anyhow::{Context, Result, bail};
use prt_sphere::{LatLongMap, Sky, SunSky};
use prt_texture::Limits;

/// The sky options shared by the commands that light a bake.
#[derive(Debug, Clone, clap::Args)]
pub struct SkyArgs {
    /// The sky: `default` (prt's default sky, L = c (1 + 0.6 y), c = (0.9, 1.0, 1.2)),
    /// `sun[:ELEVATION,AZIMUTH[,IRRADIANCE]]` (the analytic sun + sky gradient + ground of
    /// prt_sphere::SunSky; degrees, azimuth from +Z towards +X; defaults 45,0,3), or a file:
    /// a lat-long `.hdr` / `.exr` environment map (projected on order-3 SH) or a `.json` of SH
    /// coefficients (`{"sh": [[9 R], [9 G], [9 B]]}` or the output of `prt encode --basis sh:3`).
    #[arg(long, default_value = "default", value_name = "SKY")]
    pub sky: String,
    /// Turn the sky by DEG degrees about +Y (counter-clockwise seen from above).
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "DEG",
        allow_hyphen_values = true
    )]
    pub rotate: f32,
}

impl SkyArgs {
    /// The sky these options name, rotated.
    pub fn sky(&self) -> Result<Sky> {
        if !self.rotate.is_finite() {
            bail!("--rotate must be a finite number of degrees");
        }
        Ok(parse_sky(&self.sky)?.rotated_about_y(self.rotate))
    }
}

/// A sky from its `--sky` spelling.
pub fn parse_sky(spec: &str) -> Result<Sky> {
    if spec == "default" {
        return Ok(Sky::default());
    }
    if let Some(rest) = spec.strip_prefix("sun") {
        let usage = || format!("--sky {spec}: expected sun:ELEVATION,AZIMUTH[,IRRADIANCE]");
        let mut params = SunSky::default();
        if let Some(list) = rest.strip_prefix(':') {
            let values = list
                .split(',')
                .map(|v| v.trim().parse::<f32>())
                .collect::<Result<Vec<_>, _>>()
                .with_context(usage)?;
            match values[..] {
                [e, a] => (params.elevation_deg, params.azimuth_deg) = (e, a),
                [e, a, irradiance] => {
                    (params.elevation_deg, params.azimuth_deg) = (e, a);
                    let scale = irradiance / params.sun[0];
                    params.sun = params.sun.map(|c| c * scale);
                }
                _ => bail!(usage()),
            }
        } else if !rest.is_empty() {
            bail!("--sky {spec}: unknown sky (expected default, sun[:...] or a file)");
        }
        return Sky::sun_sky(&params).with_context(|| format!("--sky {spec}"));
    }
    let path = Path::new(spec);
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    match extension.as_str() {
        "json" => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read sky {}", path.display()))?;
            prt_export::sky_from_json(&text).with_context(|| format!("sky {}", path.display()))
        }
        "hdr" | "pic" | "exr" => {
            let map = read_envmap(path)?;
            Sky::from_latlong(&map).with_context(|| format!("sky {}", path.display()))
        }
        _ => bail!(
            "--sky {spec}: expected default, sun[:ELEVATION,AZIMUTH[,IRRADIANCE]], or a .hdr, .exr or .json file"
        ),
    }
}

/// Reads a lat-long environment map (.hdr or .exr).
pub fn read_envmap(path: &Path) -> Result<LatLongMap> {
    if !path.exists() {
        bail!("environment map {} does not exist", path.display());
    }
    let limits = Limits::default();
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let (w, h, rgb) = match extension.as_str() {
        "hdr" | "pic" => {
            let img = prt_texture::hdr::read_hdr(path, &limits)
                .with_context(|| format!("cannot read {}", path.display()))?;
            (img.width as usize, img.height as usize, img.data)
        }
        "exr" => {
            let layers = prt_texture::exr_io::read_exr(path, &limits)
                .with_context(|| format!("cannot read {}", path.display()))?;
            let layer = layers
                .into_iter()
                .next()
                .context("the EXR file has no RGB layer")?;
            let rgb = layer
                .data
                .chunks_exact(layer.channels)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect();
            (layer.width as usize, layer.height as usize, rgb)
        }
        _ => bail!("{}: expected a .hdr or .exr lat-long map", path.display()),
    };
    Ok(LatLongMap::new(w, h, rgb)?)
}
