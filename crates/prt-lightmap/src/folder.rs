//! Reading back the folder `prt lightmap` writes (docs/formats.md, "Lightmap folder"): its
//! manifest, the lightmap as a KTX2 array (irradiance, then one layer per basis function) and
//! the per-triangle lightmap UVs, each parsed from bytes with [`prt_texture::Limits`] checked
//! before allocating; a NaN or infinite value is an error naming where it is.

use glam::{Vec2, Vec3};
use prt_texture::{Ktx2Texture, Limits, PixelFormat};
use serde::Deserialize;

use crate::{Lightmap, LightmapBasis, LightmapError};

/// File name of a lightmap folder's manifest.
pub const LIGHTMAP_MANIFEST: &str = "manifest.json";

/// Largest manifest accepted, bytes.
pub const MAX_MANIFEST_BYTES: u64 = 16 << 20;

/// What a lightmap folder's manifest says that a reader needs.
#[derive(Debug, Clone, PartialEq)]
pub struct LightmapManifest {
    /// The scene the lightmap belongs to, as given to `prt lightmap` (a glTF path), or `None`
    /// for the built-in Cornell box.
    pub scene: Option<String>,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// The basis of the coefficient layers.
    pub basis: LightmapBasis,
    /// The SG lobes (tangent frame) of an `sg:N` basis: unit axes and their shared sharpness.
    pub sg: Option<(Vec<Vec3>, f32)>,
    /// Samples per texel behind the values.
    pub samples_per_texel: u32,
    /// File name of the KTX2 lightmap, inside the folder.
    pub ktx2: String,
    /// File name of the lightmap UVs, inside the folder.
    pub uvs: String,
}

#[derive(Deserialize)]
struct RawManifest {
    scene: Option<String>,
    width: u32,
    height: u32,
    basis: String,
    functions: usize,
    sg: Option<RawSg>,
    samples_per_texel: u32,
    files: RawFiles,
}

#[derive(Deserialize)]
struct RawSg {
    axes: Vec<[f32; 3]>,
    sharpness: f32,
}

#[derive(Deserialize)]
struct RawFiles {
    ktx2: String,
    uvs: String,
}

/// What `prt lightmap` writes as the scene of the built-in Cornell box.
const BUILT_IN_SCENE: &str = "built-in Cornell box";

/// A file name inside the folder: no separators, not `.` or `..`.
fn plain_file_name(what: &'static str, name: &str) -> Result<String, LightmapError> {
    if name.is_empty() || name == "." || name == ".." || name.contains(['/', '\\', '\0']) {
        return Err(LightmapError::invalid(
            what,
            format!("{name:?} is not a file name inside the folder"),
        ));
    }
    Ok(name.to_string())
}

impl LightmapManifest {
    /// Parses `manifest.json` (at most [`MAX_MANIFEST_BYTES`]).
    ///
    /// Errors: malformed JSON or missing fields, an unknown basis, a function count or SG lobe
    /// set that does not match the basis, non-finite or non-unit SG axes, a zero size, file
    /// names that leave the folder.
    pub fn parse(bytes: &[u8]) -> Result<Self, LightmapError> {
        if bytes.len() as u64 > MAX_MANIFEST_BYTES {
            return Err(LightmapError::invalid(
                "lightmap manifest",
                format!("{} bytes, over {MAX_MANIFEST_BYTES}", bytes.len()),
            ));
        }
        let raw: RawManifest = serde_json::from_slice(bytes)
            .map_err(|e| LightmapError::invalid("lightmap manifest", e.to_string()))?;
        let basis = LightmapBasis::parse(&raw.basis)?;
        if raw.functions != basis.len() {
            return Err(LightmapError::invalid(
                "lightmap manifest",
                format!(
                    "functions {} for basis {} ({} expected)",
                    raw.functions,
                    raw.basis,
                    basis.len()
                ),
            ));
        }
        if raw.width == 0 || raw.height == 0 {
            return Err(LightmapError::invalid(
                "lightmap size",
                format!("{}×{}", raw.width, raw.height),
            ));
        }
        let sg = match (basis, raw.sg) {
            (LightmapBasis::Sg { lobes }, Some(sg)) => {
                if sg.axes.len() != lobes {
                    return Err(LightmapError::invalid(
                        "SG lobes",
                        format!("{} axes for sg:{lobes}", sg.axes.len()),
                    ));
                }
                for (i, a) in sg.axes.iter().enumerate() {
                    let axis = Vec3::from_array(*a);
                    if !axis.is_finite() {
                        return Err(LightmapError::NonFinite {
                            what: "SG axis",
                            index: i,
                        });
                    }
                    if (axis.length() - 1.0).abs() > 1e-3 {
                        return Err(LightmapError::invalid(
                            "SG lobes",
                            format!("axis {i} is {a:?}, not unit"),
                        ));
                    }
                }
                if !(sg.sharpness.is_finite() && sg.sharpness >= 0.0) {
                    return Err(LightmapError::invalid(
                        "SG lobes",
                        format!("sharpness {}", sg.sharpness),
                    ));
                }
                Some((
                    sg.axes.iter().map(|a| Vec3::from_array(*a)).collect(),
                    sg.sharpness,
                ))
            }
            (LightmapBasis::Sg { .. }, None) => {
                return Err(LightmapError::invalid(
                    "lightmap manifest",
                    "an sg basis without its `sg` lobes",
                ));
            }
            _ => None,
        };
        Ok(LightmapManifest {
            scene: raw.scene.filter(|s| s != BUILT_IN_SCENE),
            width: raw.width,
            height: raw.height,
            basis,
            sg,
            samples_per_texel: raw.samples_per_texel,
            ktx2: plain_file_name("lightmap file", &raw.files.ktx2)?,
            uvs: plain_file_name("UV file", &raw.files.uvs)?,
        })
    }
}

/// A lightmap folder read back: the lightmap and, per scene triangle, its lightmap UVs in
/// texels (the convention of [`crate::Atlas::uvs`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LightmapFolder {
    /// The manifest.
    pub manifest: LightmapManifest,
    /// The lightmap; `covered` marks the texels with data (written or dilated: the KTX2's
    /// alpha).
    pub lightmap: Lightmap,
    /// Per scene triangle, its three lightmap UVs in texels.
    pub uvs: Vec<[Vec2; 3]>,
}

impl LightmapFolder {
    /// Parses the folder's KTX2 lightmap and UV file for `manifest`.
    ///
    /// Errors: a KTX2 that is malformed or over `limits`, not an RGBA32F 2D array of
    /// `1 + functions` layers of the manifest's size, or holding a NaN or infinite value
    /// (named by layer and texel); a UV file whose length is not a whole number of triangles
    /// (24 bytes each), over `limits.max_bytes`, or holding a NaN or infinite UV (or one that
    /// overflows once scaled to texels).
    pub fn parse(
        manifest: LightmapManifest,
        ktx2: &[u8],
        uvs: &[u8],
        limits: &Limits,
    ) -> Result<Self, LightmapError> {
        let texture = Ktx2Texture::from_bytes(ktx2, limits)
            .map_err(|e| LightmapError::invalid("lightmap KTX2", e.to_string()))?;
        let shape = texture.shape();
        let layers = 1 + manifest.basis.len();
        if texture.format() != PixelFormat::R32G32B32A32Sfloat
            || (shape.width, shape.height) != (manifest.width, manifest.height)
            || shape.depth != 0
            || shape.faces != 1
            || shape.layers.max(1) as usize != layers
        {
            return Err(LightmapError::invalid(
                "lightmap KTX2",
                format!(
                    "{:?} {}×{} with {} layers, expected RGBA32F {}×{} with {layers}",
                    texture.format(),
                    shape.width,
                    shape.height,
                    shape.layers.max(1),
                    manifest.width,
                    manifest.height
                ),
            ));
        }
        let level = texture
            .level_f32(0)
            .map_err(|e| LightmapError::invalid("lightmap KTX2", e.to_string()))?;
        let texels = manifest.width as usize * manifest.height as usize;
        if level.len() != 4 * texels * layers {
            return Err(LightmapError::invalid(
                "lightmap KTX2",
                format!("{} values, expected {}", level.len(), 4 * texels * layers),
            ));
        }
        if let Some(at) = level.iter().position(|v| !v.is_finite()) {
            let (layer, texel) = (at / (4 * texels), at % (4 * texels) / 4);
            return Err(LightmapError::invalid(
                "lightmap KTX2",
                format!(
                    "{} in layer {layer} ({}) at texel ({}, {})",
                    level[at],
                    if layer == 0 {
                        "irradiance".to_string()
                    } else {
                        format!("c{:02}", layer - 1)
                    },
                    texel % manifest.width as usize,
                    texel / manifest.width as usize
                ),
            ));
        }
        let rgb = |layer: usize| -> Vec<f32> {
            level[4 * texels * layer..4 * texels * (layer + 1)]
                .chunks_exact(4)
                .flat_map(|t| [t[0], t[1], t[2]])
                .collect()
        };
        let covered = level[..4 * texels]
            .chunks_exact(4)
            .map(|t| t[3] > 0.0)
            .collect();
        let lightmap = Lightmap {
            width: manifest.width,
            height: manifest.height,
            basis: manifest.basis,
            coefficients: (1..layers).map(rgb).collect(),
            irradiance: rgb(0),
            covered,
            samples_per_texel: manifest.samples_per_texel,
        };
        let uvs = parse_uvs(uvs, manifest.width, manifest.height, limits)?;
        Ok(LightmapFolder {
            manifest,
            lightmap,
            uvs,
        })
    }
}

/// `lightmap_uvs.bin`: per triangle, three (u, v) pairs of little-endian f32 in 0..1 (origin
/// top-left), scaled to texels.
fn parse_uvs(
    bytes: &[u8],
    width: u32,
    height: u32,
    limits: &Limits,
) -> Result<Vec<[Vec2; 3]>, LightmapError> {
    if !bytes.len().is_multiple_of(24) {
        return Err(LightmapError::invalid(
            "lightmap UVs",
            format!(
                "{} bytes is not a whole number of triangles (24 each)",
                bytes.len()
            ),
        ));
    }
    // The decoded UVs take as many bytes as the file.
    if bytes.len() as u64 > limits.max_bytes {
        return Err(LightmapError::invalid(
            "lightmap UVs",
            format!(
                "{} bytes, over the limit of {}",
                bytes.len(),
                limits.max_bytes
            ),
        ));
    }
    let size = Vec2::new(width as f32, height as f32);
    bytes
        .chunks_exact(24)
        .enumerate()
        .map(|(t, chunk)| {
            let value = |k: usize| {
                f32::from_le_bytes([
                    chunk[4 * k],
                    chunk[4 * k + 1],
                    chunk[4 * k + 2],
                    chunk[4 * k + 3],
                ])
            };
            // Checked after scaling: a finite UV near f32::MAX overflows to infinity in texels.
            let uv = [0, 1, 2].map(|p| Vec2::new(value(2 * p), value(2 * p + 1)) * size);
            if uv.iter().all(|p| p.is_finite()) {
                Ok(uv)
            } else {
                Err(LightmapError::NonFinite {
                    what: "lightmap UV",
                    index: t,
                })
            }
        })
        .collect()
}

impl Lightmap {
    /// Bilinear lookup of every coefficient layer at atlas position `uv` in texels (as
    /// [`Lightmap::irradiance_at`] filters), into `out` (one RGB value per basis function).
    ///
    /// # Panics
    /// If `out` is shorter than the basis.
    pub fn coefficients_at(&self, uv: Vec2, out: &mut [Vec3]) {
        let (w, h) = (self.width as i64, self.height as i64);
        let p = uv - Vec2::splat(0.5);
        let (x0, y0) = (p.x.floor(), p.y.floor());
        let (fx, fy) = (p.x - x0, p.y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let index = |x: i64, y: i64| (y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize;
        let corners = [
            (index(x0, y0), (1.0 - fx) * (1.0 - fy)),
            (index(x0 + 1, y0), fx * (1.0 - fy)),
            (index(x0, y0 + 1), (1.0 - fx) * fy),
            (index(x0 + 1, y0 + 1), fx * fy),
        ];
        for (o, layer) in out.iter_mut().zip(&self.coefficients) {
            *o = corners.iter().fold(Vec3::ZERO, |s, &(i, weight)| {
                s + weight * Vec3::from_slice(&layer[3 * i..3 * i + 3])
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest_json(basis: &str, functions: usize, sg: &str) -> String {
        format!(
            r#"{{"scene": "built-in Cornell box", "width": 2, "height": 1, "basis": "{basis}",
            "functions": {functions}, "sg": {sg}, "samples_per_texel": 4,
            "files": {{"ktx2": "lightmap.ktx2", "uvs": "lightmap_uvs.bin"}}}}"#
        )
    }

    fn ktx2(layers: u32, values: &[f32]) -> Vec<u8> {
        let shape = prt_texture::Shape::d2_array(2, 1, layers);
        Ktx2Texture::from_f32(PixelFormat::R32G32B32A32Sfloat, shape, &[values.to_vec()])
            .unwrap()
            .to_bytes()
            .unwrap()
    }

    fn uv_bytes(values: &[f32]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn a_folder_reads_back() {
        let manifest =
            LightmapManifest::parse(manifest_json("sh:1", 1, "null").as_bytes()).unwrap();
        assert_eq!(manifest.scene, None);
        let values: Vec<f32> = (0..16).map(|i| i as f32).collect();
        let uvs = uv_bytes(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
        let folder =
            LightmapFolder::parse(manifest, &ktx2(2, &values), &uvs, &Limits::small()).unwrap();
        assert_eq!(folder.lightmap.irradiance, [0.0, 1.0, 2.0, 4.0, 5.0, 6.0]);
        assert_eq!(
            folder.lightmap.coefficients,
            [vec![8.0, 9.0, 10.0, 12.0, 13.0, 14.0]]
        );
        assert_eq!(folder.lightmap.covered, [true, true]);
        assert_eq!(
            folder.uvs,
            [[Vec2::ZERO, Vec2::new(2.0, 0.0), Vec2::new(0.0, 1.0)]]
        );
        let mut c = [Vec3::ZERO];
        folder.lightmap.coefficients_at(Vec2::new(1.0, 0.5), &mut c);
        assert_eq!(c[0], Vec3::new(10.0, 11.0, 12.0));
    }

    #[test]
    fn bad_folders_are_errors_naming_where() {
        let sh = || LightmapManifest::parse(manifest_json("sh:1", 1, "null").as_bytes()).unwrap();
        // The writer refuses NaN: a sentinel's bytes are replaced in the file.
        let mut values: Vec<f32> = (0..16).map(|i| i as f32).collect();
        values[13] = 12345.0;
        let mut bytes = ktx2(2, &values);
        let at = bytes
            .windows(4)
            .position(|w| w == 12345.0f32.to_le_bytes())
            .unwrap();
        bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let uvs = uv_bytes(&[0.0; 6]);
        let e = LightmapFolder::parse(sh(), &bytes, &uvs, &Limits::small()).unwrap_err();
        assert!(
            e.to_string().contains("layer 1 (c00) at texel (1, 0)"),
            "{e}"
        );
        let values: Vec<f32> = (0..16).map(|i| i as f32).collect();
        let e = LightmapFolder::parse(sh(), &ktx2(2, &values), &uvs[..20], &Limits::small());
        assert!(e.is_err());
        let e = LightmapFolder::parse(
            sh(),
            &ktx2(2, &values),
            &uv_bytes(&[0.0, 0.0, f32::INFINITY, 0.0, 0.0, 0.0]),
            &Limits::small(),
        )
        .unwrap_err();
        assert_eq!(
            e,
            LightmapError::NonFinite {
                what: "lightmap UV",
                index: 0
            }
        );
        // A finite UV that overflows in texels (found by fuzzing).
        let e = LightmapFolder::parse(
            sh(),
            &ktx2(2, &values),
            &uv_bytes(&[0.0, 0.0, 0.0, 0.0, 3e38, 0.0]),
            &Limits::small(),
        )
        .unwrap_err();
        assert_eq!(
            e,
            LightmapError::NonFinite {
                what: "lightmap UV",
                index: 0
            }
        );
        // Three layers where sh:1 has two.
        let e = LightmapFolder::parse(sh(), &ktx2(3, &[0.0; 24]), &uvs, &Limits::small());
        assert!(e.is_err());
        for bad in [
            manifest_json("sh:1", 2, "null"),
            manifest_json("sg:2", 2, "null"),
            manifest_json("sg:1", 1, r#"{"axes": [[0, 2, 0]], "sharpness": 1}"#),
            manifest_json("sg:1", 1, r#"{"axes": [[0, 1, 0]], "sharpness": -1}"#),
            manifest_json("sh:1", 1, "null").replace("lightmap.ktx2", "../x"),
            "{".to_string(),
        ] {
            assert!(LightmapManifest::parse(bad.as_bytes()).is_err(), "{bad}");
        }
        let sg = manifest_json("sg:1", 1, r#"{"axes": [[0, 1, 0]], "sharpness": 0.69}"#);
        assert_eq!(
            LightmapManifest::parse(sg.as_bytes()).unwrap().sg,
            Some((vec![Vec3::Y], 0.69))
        );
    }
}
