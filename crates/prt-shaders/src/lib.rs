//! # prt-shaders — render straight from prt's filterable MBD container
//!
//! WGSL (wgpu, Bevy) and GLSL ES 3.00 (WebGL2) sources that evaluate a Moving Basis
//! Decomposition written by `prt bake` in the filterable layout (docs/formats.md), with no
//! decompression step:
//!
//! * **the lighting pass**, run when the sky changes: every basis vector `B_{n,l}` (324-D
//!   transfer) becomes incident radiance as SH9 RGB, `b̃_{n,l}[c·9+i] = Σ_j (D_ij + T^c_ij) s^c_j`,
//!   written into a small tiled rgba16f volume over the basis grid (a WGSL compute shader; a
//!   GLSL fragment pass drawn once per z slice, as WebGL2 has no compute);
//! * **the per-pixel reconstruction** `f̃(x) = Σ_l c_l(x) b̃_l(x)`: ⌈L/4⌉ hardware-filtered
//!   fetches of the coefficient volume and 7·L of the lit volume, the coefficients
//!   dequantised with their per-channel scale and bias;
//! * **irradiance** from SH9 for a normal (clamped-cosine convolution);
//! * **lightmap texels** in a sphere basis (`prt lightmap --basis sg:N | sh:N`): diffuse
//!   irradiance and a GGX specular lobe for a view and roughness, reconstructed in the
//!   fragment shader from a texel's coefficients (Roughton 2020's Figure 2, after Neubelt and
//!   Pettineo's SG specular).
//!
//! Each hat grid is a tiled 3D texture whose node `i` is texel centre `i` of its tile, so
//! trilinear filtering at `mbd_local` coordinates computes the hat sums; clamping to the grid's
//! box keeps every footprint inside its tile.
//!
//! | item | what it is, when to use it |
//! |---|---|
//! | [`wgsl_reconstruct`], [`wgsl_light`] | complete WGSL modules for a rank (reconstruction functions with their bindings; the lighting compute shader) |
//! | [`glsl_reconstruct`], [`glsl_light`] | GLSL ES 3.00 sources for a rank: the reconstruction functions (append your `main`), the lighting fragment shader |
//! | [`wgsl_reconstruct_for`], [`glsl_reconstruct_for`], [`CoefficientStorage`] | the reconstruction for a coefficient volume dense or in bricks (one indirection fetch per pixel) |
//! | [`wgsl`], [`glsl`] | the source files as strings, for a page or an engine that assembles them itself |
//! | [`LIT_GROUPS`], [`BASIS_GROUPS`], [`coefficient_groups`] | texels per lit basis vector, per raw basis vector, per coefficient node |
//! | [`wgsl_lightmap_sg`], [`wgsl_lightmap_sh`], [`glsl_lightmap_sg`], [`glsl_lightmap_sh`] | the lightmap function libraries (`lm_sg_diffuse`, `lm_sg_specular`, `lm_sh_diffuse`, `lm_sh_specular`) for an SG lobe set or for SH |
//! | [`lightmap`] | the same lightmap math on the CPU, operation for operation |
//!
//! The sources are validated by naga in this crate's tests, and a CPU emulation of exactly
//! their math over the decoded texels is checked against the model they come from.
#![deny(missing_docs)]

pub mod lightmap;

use thiserror::Error;

/// Errors of the source assemblers.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ShaderError {
    /// The SG lobe set cannot be written into a shader.
    #[error("invalid SG lobes: {0}")]
    InvalidLobes(String),
}

/// Texels (RGBA) per lit basis vector: 27 values (SH9 RGB), the 28th is 0.
pub const LIT_GROUPS: usize = 7;
/// Texels (RGBA) per raw basis vector: 324 values.
pub const BASIS_GROUPS: usize = 81;

/// How a container stores its coefficient volume (its `coefficients` array's `layout`), as the
/// shaders read it; `prt_bake::container::CoefficientLayout` is the writer's choice, which may be `Auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CoefficientStorage {
    /// `volume`: ⌈L/4⌉ tiles stacked along z.
    #[default]
    Dense,
    /// `bricks`: a brick atlas read through an indirection texture.
    Bricks,
}

/// Texels (RGBA) per coefficient node for rank `rank`: ⌈L/4⌉.
pub fn coefficient_groups(rank: usize) -> usize {
    rank.div_ceil(4)
}

/// The WGSL source files.
pub mod wgsl {
    /// `MbdGrid`, the tile addressing, SH9 and irradiance; needs `const RANK: u32` first.
    pub const COMMON: &str = include_str!("../shaders/wgsl/common.wgsl");
    /// `mbd_incident_radiance(x)` with its bindings (group 0, bindings 0–3); needs [`COMMON`].
    pub const RECONSTRUCT: &str = include_str!("../shaders/wgsl/reconstruct.wgsl");
    /// The dense coefficient volume's `mbd_coefficient_site` / `mbd_coefficient_texel`.
    pub const COEFFICIENTS_DENSE: &str = include_str!("../shaders/wgsl/coefficients_dense.wgsl");
    /// The bricked coefficient volume's, with the indirection binding (group 0, binding 4).
    pub const COEFFICIENTS_BRICKS: &str = include_str!("../shaders/wgsl/coefficients_bricks.wgsl");
    /// The lighting compute shader `mbd_light_main` (group 0, bindings 0–3); needs [`COMMON`].
    pub const LIGHT: &str = include_str!("../shaders/wgsl/light.wgsl");
    /// Lightmap texels: the tangent frame, SG integrals, Hill's SG irradiance, the warped GGX
    /// lobe (`lm_*`); needs nothing before it.
    pub const LIGHTMAP_COMMON: &str = include_str!("../shaders/wgsl/lightmap_common.wgsl");
    /// `lm_sg_diffuse` and `lm_sg_specular`; needs `LM_SG_LOBES`, `LM_SG_SHARPNESS`,
    /// `LM_SG_AXES` and [`LIGHTMAP_COMMON`].
    pub const LIGHTMAP_SG: &str = include_str!("../shaders/wgsl/lightmap_sg.wgsl");
    /// `lm_sh_diffuse` and `lm_sh_specular` (9 coefficients); needs [`LIGHTMAP_COMMON`].
    pub const LIGHTMAP_SH: &str = include_str!("../shaders/wgsl/lightmap_sh.wgsl");
}

/// The GLSL source files: a body common to GLSL ES 3.00 and 4.50, and the WebGL2 declarations.
pub mod glsl {
    /// `MbdGrid`, the tile addressing and irradiance; needs `#define RANK` first.
    pub const COMMON: &str = include_str!("../shaders/glsl/common.glsl");
    /// `mbd_incident_radiance(x, out sh[7])`; needs [`COMMON`] and [`RECONSTRUCT_ES`] (or other
    /// declarations of the same names).
    pub const RECONSTRUCT: &str = include_str!("../shaders/glsl/reconstruct.glsl");
    /// WebGL2 uniforms and samplers of [`RECONSTRUCT`].
    pub const RECONSTRUCT_ES: &str = include_str!("../shaders/glsl/reconstruct_es.glsl");
    /// The dense coefficient volume's `mbd_coefficient_site` / `mbd_coefficient_texel` (before
    /// [`RECONSTRUCT`]).
    pub const COEFFICIENTS_DENSE: &str = include_str!("../shaders/glsl/coefficients_dense.glsl");
    /// The bricked coefficient volume's (before [`RECONSTRUCT`]); needs [`BRICKS_ES`].
    pub const COEFFICIENTS_BRICKS: &str = include_str!("../shaders/glsl/coefficients_bricks.glsl");
    /// WebGL2 uniform and sampler of [`COEFFICIENTS_BRICKS`].
    pub const BRICKS_ES: &str = include_str!("../shaders/glsl/bricks_es.glsl");
    /// The lighting fragment shader (with `main`); needs [`COMMON`] and [`LIGHT_ES`].
    pub const LIGHT: &str = include_str!("../shaders/glsl/light.glsl");
    /// WebGL2 uniforms, samplers and output of [`LIGHT`].
    pub const LIGHT_ES: &str = include_str!("../shaders/glsl/light_es.glsl");
    /// Lightmap texels: the shared `lm_*` functions (GLSL ES 3.00 and 4.50).
    pub const LIGHTMAP_COMMON: &str = include_str!("../shaders/glsl/lightmap_common.glsl");
    /// `lm_sg_diffuse` and `lm_sg_specular`; needs `LM_SG_LOBES`, `LM_SG_SHARPNESS`,
    /// `LM_SG_AXES` and [`LIGHTMAP_COMMON`].
    pub const LIGHTMAP_SG: &str = include_str!("../shaders/glsl/lightmap_sg.glsl");
    /// `lm_sh_diffuse` and `lm_sh_specular` (9 coefficients); needs [`LIGHTMAP_COMMON`].
    pub const LIGHTMAP_SH: &str = include_str!("../shaders/glsl/lightmap_sh.glsl");
    /// The GLSL ES 3.00 header: version and precisions (must come first).
    pub const ES_HEADER: &str = "#version 300 es\nprecision highp float;\nprecision highp int;\nprecision highp sampler3D;\nprecision highp sampler2D;\n";
}

fn wgsl_header(rank: usize) -> String {
    format!("const RANK: u32 = {rank}u;\n")
}

fn glsl_header(rank: usize) -> String {
    format!("{}#define RANK {rank}\n", glsl::ES_HEADER)
}

/// The WGSL reconstruction module for rank `rank` and a dense coefficient volume:
/// `mbd_incident_radiance(x)` and `mbd_irradiance(sh, normal)` with the bindings of
/// `reconstruct.wgsl`; add your entry points.
pub fn wgsl_reconstruct(rank: usize) -> String {
    wgsl_reconstruct_for(rank, CoefficientStorage::Dense)
}

/// [`wgsl_reconstruct`] for a coefficient volume in `layout` (bricks add binding 4, the
/// indirection texture).
pub fn wgsl_reconstruct_for(rank: usize, layout: CoefficientStorage) -> String {
    let coefficients = match layout {
        CoefficientStorage::Dense => wgsl::COEFFICIENTS_DENSE,
        CoefficientStorage::Bricks => wgsl::COEFFICIENTS_BRICKS,
    };
    [
        &wgsl_header(rank),
        wgsl::COMMON,
        wgsl::RECONSTRUCT,
        coefficients,
    ]
    .concat()
}

/// The WGSL lighting compute shader for rank `rank` (entry point `mbd_light_main`,
/// workgroup 4×4×4, one invocation per texel of the lit volume).
pub fn wgsl_light(rank: usize) -> String {
    [&wgsl_header(rank), wgsl::COMMON, wgsl::LIGHT].concat()
}

/// The GLSL ES 3.00 reconstruction functions for rank `rank` and a dense coefficient volume
/// (header, declarations, `mbd_incident_radiance`, `mbd_irradiance`): append your fragment
/// shader's `main`.
pub fn glsl_reconstruct(rank: usize) -> String {
    glsl_reconstruct_for(rank, CoefficientStorage::Dense)
}

/// [`glsl_reconstruct`] for a coefficient volume in `layout` (bricks add `u_mbd_bricks` and the
/// indirection sampler `u_mbd_coefficient_indirection`).
pub fn glsl_reconstruct_for(rank: usize, layout: CoefficientStorage) -> String {
    let header = glsl_header(rank);
    let parts: &[&str] = match layout {
        CoefficientStorage::Dense => &[
            &header,
            glsl::COMMON,
            glsl::RECONSTRUCT_ES,
            glsl::COEFFICIENTS_DENSE,
            glsl::RECONSTRUCT,
        ],
        CoefficientStorage::Bricks => &[
            &header,
            glsl::COMMON,
            glsl::RECONSTRUCT_ES,
            glsl::BRICKS_ES,
            glsl::COEFFICIENTS_BRICKS,
            glsl::RECONSTRUCT,
        ],
    };
    parts.concat()
}

/// The GLSL ES 3.00 lighting fragment shader for rank `rank`, complete.
pub fn glsl_light(rank: usize) -> String {
    [
        &glsl_header(rank),
        glsl::COMMON,
        glsl::LIGHT_ES,
        glsl::LIGHT,
    ]
    .concat()
}

/// Checks an SG lobe set (the manifest's `sg`: unit axes in the tangent frame, one finite
/// sharpness ≥ 0) and writes its numbers as shader literals.
fn sg_literals(axes: &[[f32; 3]], sharpness: f32) -> Result<(Vec<String>, String), ShaderError> {
    if axes.is_empty() || axes.len() > 256 {
        return Err(ShaderError::InvalidLobes(format!(
            "{} lobes (1..=256)",
            axes.len()
        )));
    }
    if !(sharpness.is_finite() && sharpness >= 0.0) {
        return Err(ShaderError::InvalidLobes(format!("sharpness {sharpness}")));
    }
    let literal = |v: f32| format!("{v:?}");
    let axes = axes
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let length = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            if a.iter().all(|v| v.is_finite()) && (length - 1.0).abs() <= 1e-3 {
                Ok(format!(
                    "{}, {}, {}",
                    literal(a[0]),
                    literal(a[1]),
                    literal(a[2])
                ))
            } else {
                Err(ShaderError::InvalidLobes(format!(
                    "axis {i} is {a:?}, not unit"
                )))
            }
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((axes, literal(sharpness)))
}

/// The WGSL lightmap library for SG texels with these lobes (the manifest's `sg.axes` and
/// `sg.sharpness`): `lm_tangent_frame`, `lm_to_tangent`, `lm_sg_diffuse(coefficients, n)` and
/// `lm_sg_specular(coefficients, n, v, roughness, f0)`; add your entry points.
pub fn wgsl_lightmap_sg(axes: &[[f32; 3]], sharpness: f32) -> Result<String, ShaderError> {
    let (axes, sharpness) = sg_literals(axes, sharpness)?;
    let vectors: Vec<String> = axes.iter().map(|a| format!("vec3<f32>({a})")).collect();
    let header = format!(
        "const LM_SG_LOBES: u32 = {}u;\nconst LM_SG_SHARPNESS: f32 = {sharpness};\nconst LM_SG_AXES = array<vec3<f32>, {}>({});\n",
        axes.len(),
        axes.len(),
        vectors.join(", ")
    );
    Ok([&header, wgsl::LIGHTMAP_COMMON, wgsl::LIGHTMAP_SG].concat())
}

/// The WGSL lightmap library for SH texels: `lm_tangent_frame`, `lm_to_tangent`,
/// `lm_sh_diffuse(coefficients, n)` and `lm_sh_specular(coefficients, n, v, roughness, f0)`.
pub fn wgsl_lightmap_sh() -> String {
    [wgsl::LIGHTMAP_COMMON, wgsl::LIGHTMAP_SH].concat()
}

/// [`wgsl_lightmap_sg`] in GLSL ES 3.00 (header included): append your `main`.
pub fn glsl_lightmap_sg(axes: &[[f32; 3]], sharpness: f32) -> Result<String, ShaderError> {
    Ok([glsl::ES_HEADER, &glsl_lightmap_sg_body(axes, sharpness)?].concat())
}

/// [`wgsl_lightmap_sh`] in GLSL ES 3.00 (header included): append your `main`.
pub fn glsl_lightmap_sh() -> String {
    [glsl::ES_HEADER, glsl::LIGHTMAP_COMMON, glsl::LIGHTMAP_SH].concat()
}

/// The SG library without a version line, for a GLSL 4.50 or ES 3.00 source of your own.
pub fn glsl_lightmap_sg_body(axes: &[[f32; 3]], sharpness: f32) -> Result<String, ShaderError> {
    let (axes, sharpness) = sg_literals(axes, sharpness)?;
    let vectors: Vec<String> = axes.iter().map(|a| format!("vec3({a})")).collect();
    let header = format!(
        "#define LM_SG_LOBES {}\nconst float LM_SG_SHARPNESS = {sharpness};\nconst vec3 LM_SG_AXES[LM_SG_LOBES] = vec3[LM_SG_LOBES]({});\n",
        axes.len(),
        vectors.join(", ")
    );
    Ok([&header, glsl::LIGHTMAP_COMMON, glsl::LIGHTMAP_SG].concat())
}
