//! # prt-trace — scenes, ray queries and the transfer-volume baker of prt
//!
//! This crate produces the data that Moving Basis Decomposition compresses: the
//! 324-dimensional light-transport volumes of Silvennoinen and Sloan, "Moving Basis
//! Decomposition for Precomputed Light Transport" (EGSR 2021), traced out of real scenes.
//!
//! * **Scenes** ([`Scene`]): glTF 2.0 files flattened to world-space triangles with diffuse
//!   materials, lights and cameras ([`Scene::load_gltf`]), or built-in scenes: the Cornell box,
//!   a ground plane under open sky, a closed box, the empty scene, an outdoor town (terrain and
//!   buildings, [`Scene::outdoor_town`]).
//! * **Ray queries** ([`RayTracer`]): a compressed wide BVH (obvhs CWBVH, Ylitie et al. 2017)
//!   with the triangles reordered into BVH order; closest hits and occlusion (stopping at the
//!   first hit), single or batched over rayon. Where the CPU has x86-64-v3 (AVX2, FMA, BMI,
//!   LZCNT, POPCNT; detected at run time, see [`RayTracer::instruction_set`]) the traversal runs
//!   compiled for it with an 8-wide child-box test, with bit-identical results.
//! * **The baker** ([`TransferBaker`]): for every voxel centre `x` of a grid, with real SH of
//!   order 3 (9 coefficients, [`sh::sh9`], evaluated by `prt-sphere`) for distant sky light,
//!   - direct transfer `D_ij = ∫ V(x, ω) Y_i(ω) Y_j(ω) dω` (sky visibility), and
//!   - one-bounce direct-to-indirect transfer per colour channel
//!     `T^c_ij = ∫ Y_i(ω) L^c_j(h(x, ω), -ω) dω`, where `h` is the first hit and
//!     `L^c_j(h) = (ρ_c/π) ∫_H V(h, ω') (n·ω') Y_j(ω') dω'` is the radiance leaving `h` when the
//!     sky is `Y_j`.
//! * **Sparse bricks** ([`TransferBaker::bake_bricks`], [`bricks::BrickOptions`], [`bricks::BrickMap`],
//!   [`bricks::BrickedVolume`]): a probe pass (the validity test's rays only) classifies bricks of 4³
//!   voxels; bricks without a valid voxel (opt-in: far from geometry) are neither traced nor
//!   stored, and the kept voxels equal the dense bake's bit for bit. For large grids with much
//!   solid or outside space.
//! * **Many lights** ([`trace_vpls`](manylight::trace_vpls), [`GBuffer`](camera::GBuffer), [`VplOracle`](manylight::VplOracle)): virtual point lights by
//!   particle tracing from the emitters (instant radiosity, Keller 1997; a sun and sky for
//!   scenes without emitters), a pinhole view ([`PinholeView`](camera::PinholeView): the glTF camera or a framing of
//!   the bounds) with a G-buffer of gather points, and the pixel × VPL matrix with shadow rays as
//!   a [`prt_core::MatrixOracle`] (RGB) for the row-column sampling of Hašan et al. 2007, plus
//!   its brute-force reference image. Lights files ([`read_lights_file`](manylight::read_lights_file)) bring user-made
//!   point lights in their place.
//! * **The scene mesh file** ([`mesh`]: [`write_mesh`](mesh::write_mesh),
//!   [`read_mesh`](mesh::read_mesh), [`encode_mesh`](mesh::encode_mesh),
//!   [`decode_mesh`](mesh::decode_mesh), [`MeshError`](mesh::MeshError)): a scene's triangles, materials and cameras in a small binary format
//!   (`scene.mesh` in a bake folder) that `prt render` and a browser read back.
//! * **Cube-map shadow rays** ([`CubeRays`](relight::CubeRays)): from a surface point towards every texel of a
//!   cube map of distant light, with exact sub-texel solid angles; the sampling under per-pixel
//!   wavelet transport, where a transport row has one entry per lighting texel.
//! * **Per-pixel wavelet transport** ([`PixelTransportBaker`](relight::PixelTransportBaker), [`PixelTransport`](relight::PixelTransport),
//!   [`PixelRelighter`](relight::PixelRelighter)): for a fixed camera, every pixel's row over a cube map of light
//!   (direct, or with one diffuse bounce), Haar-transformed, sparsified ([`Sparsify`](relight::Sparsify)) and
//!   quantised for prt-wavelet's relighting engine; written to and read from a compact file.
//! * **BRDF-editing transport** ([`trace_half_angle_transport`](relight::trace_half_angle_transport)): per pixel, the glossy
//!   transport against the bins of an editable half-angle BRDF curve under fixed view and cube-map
//!   lighting (Ben-Artzi et al. 2006), so that the image is linear in the curve.
//!
//! ## Where things are
//! The front door is at the root: [`Scene`] and [`LoadOptions`], [`RayTracer`] and [`Hit`],
//! [`TransferBaker`] with [`BakeOptions`] (and its [`AdaptiveSampling`] and [`DenoiseOptions`])
//! giving a [`TransferVolume`] of [`TRANSFER_DIM`] per voxel and its [`BakeStats`], the
//! [`LitVolume`] a sky lights it to, and [`TraceError`]. The rest, by concern:
//!
//! | module | what it holds, when to use it |
//! |---|---|
//! | [`scene`] | a scene's parts (materials, punctual lights, glTF cameras): when you build or inspect a scene |
//! | [`sh`] | the order-3 SH basis of every transfer vector (`sh9`, `SH9`): when you project or evaluate a direction yourself |
//! | [`lit`] | lighting a transfer by a sky: incident radiance and irradiance per voxel, a constant sky, the lit volume |
//! | [`camera`] | the per-pixel methods' pinhole view and G-buffer of gather points |
//! | [`bricks`] | sparse bricks: trace and store only the bricks that hold a valid voxel |
//! | [`mesh`] | the scene mesh file (`scene.mesh`) that `prt render` and a browser read |
//! | [`manylight`] | virtual point lights and the pixel × light matrix for prt-manylight |
//! | [`relight`] | per-pixel transport over a cube map of light for wavelet relighting (prt-wavelet) |
//! | [`expert`] | the baker's and the ray tracer's details, for tests and benches |
//!
//! ## Output layout
//! A [`GridField`](prt_core::GridField) of dimension [`TRANSFER_DIM`] = 324 per voxel, laid out
//! `[direct 81 | R 81 | G 81 | B 81]`; each block is a 9×9 matrix stored row-major,
//! `T[i * 9 + j]`, with row `i` the SH coefficient of incident radiance at the voxel and column
//! `j` that of the sky: `l^c_i = Σ_j (D_ij + T^c_ij) s^c_j`. `D` is symmetric. A validity mask
//! marks voxels inside geometry (more than [`BakeOptions::max_backface_fraction`] of their
//! probe rays hit back faces): their transfer is zero, and engines use the mask against leaks.
//!
//! ## Method
//! * **Directions.** Each voxel traces whole *randomly rotated icosahedra*. The 12 vertices of
//!   an icosahedron form a spherical 5-design, so for any rotation `4π/12 Σ_k Y_i Y_j = δ_ij`
//!   exactly: the empty scene gives `D = I` and a closed box `D = 0` with no sampling noise, and
//!   `0 ⪯ D ⪯ I` holds for every estimate. The rotations of successive icosahedra are
//!   Owen-scrambled Sobol' points (Burley 2020) pushed through Shoemake's uniform-rotation map,
//!   so the estimator is unbiased and stratified; the error falls at least like `1/√N`.
//! * **Surface transfer cache.** The one-bounce term needs, at every hit, a hemisphere integral.
//!   Instead of `rays per voxel × rays per hit`, every triangle carries a barycentric lattice of
//!   cache points (spacing at most one voxel edge by default), each with the 9-vector
//!   `t_j = (1/π) ∫_H V (n·ω) Y_j dω` for each reflecting side, estimated with cosine-weighted
//!   scrambled Sobol' rays. A voxel-ray hit interpolates the lattice linearly and multiplies by
//!   the albedo. [`expert::IndirectMode::BruteForce`] traces fresh rays per hit instead, and the tests
//!   check that both agree within Monte Carlo noise.
//! * **Variance, adaptive sampling, denoising** (opt-in: [`BakeOptions::adaptive`],
//!   [`BakeOptions::denoise`]). With either, a voxel's icosahedra come from [`expert::REPLICATES`]
//!   independently scrambled streams whose spread estimates its variance without bias;
//!   [`AdaptiveSampling`] stops a voxel at a target relative standard error, and the
//!   [`DenoiseOptions`] filter averages only valid neighbours visible from the voxel (no light
//!   through a wall), weighted by their difference in units of the measured noise.
//! * **Determinism.** Every random number is a function of `(seed, voxel or cache point, ray)`;
//!   sums run in a fixed order inside a voxel (f32 per icosahedron, f64 across them), so a seed
//!   gives bit-identical volumes on any thread count.
//! * **Cost control.** Invalid voxels stop after their probe rays; with explicit grid bounds,
//!   voxels outside the scene bounds plus margin are not traced at all.
//!
//! ## At the extremes
//! * A scene without triangles is [`TraceError::EmptyScene`] for baking unless explicit grid
//!   bounds are given; then `D = I` and the indirect blocks are 0 exactly.
//! * Inside a closed scene `D = 0` exactly; no sky light, so the indirect blocks are 0 too.
//! * `rays_per_voxel` is rounded up to a multiple of 12 (at least 12); the probe that decides
//!   validity likewise. Invalid voxels cost only their probe rays; with explicit bounds, voxels
//!   outside the scene bounds plus margin cost none. Both are zero and `valid = false`. A bake
//!   with no valid voxel at all is [`TraceError::NoValidVoxels`];
//!   [`BakeStats::valid_fraction`] tells how much of a grid is valid.
//! * A flat scene (all triangles in one axis-aligned plane, margin 0) gets a grid one voxel edge
//!   of its longest axis thick along the flat axis.
//! * Malformed glTF or GLB is a typed error naming the accessor, mesh and primitive, or node
//!   ([`TraceError::BadAccessor`], [`TraceError::BadPrimitive`], [`TraceError::BadNode`],
//!   [`TraceError::Buffer`], [`TraceError::Gltf`]), never a panic; an extension that changes
//!   geometry is [`TraceError::UnsupportedExtension`] when required or used without a fallback.
//!   What glTF 2.0 allows and gltf-json refuses is read: an accessor without a buffer view is
//!   zeros (a primitive whose positions or indices are such zeros has no area and is skipped
//!   unread, with a warning), a primitive without POSITION is skipped with a warning, a scene may omit `nodes`, an
//!   animation target its `node` (animations are ignored), an integer may be written `1.0`.
//!   Only the buffers holding positions, indices, `TEXCOORD_1` and morph targets (and images, when decoded)
//!   are loaded.
//! * Degenerate (zero-area) triangles are dropped and counted; NaN/Inf positions are
//!   [`TraceError::NonFinitePosition`] naming mesh, primitive and triangle; point and line
//!   primitives are skipped with a warning.
//! * Huge triangles get at most 128 cache subdivisions per edge, and the cache spacing grows until
//!   it holds at most 4 million points, so memory stays bounded (a 128³ Sponza bake peaks at
//!   2.9 GB, 2.7 GB of which is the field itself).
//!
//! ```
//! use prt_core::NoProgress;
//! use prt_trace::lit::constant_sky;
//! use prt_trace::{BakeOptions, Scene, TransferBaker};
//!
//! let scene = Scene::cornell_box();
//! let options = BakeOptions { resolution: [6, 6, 6], rays_per_voxel: 96, cache_rays: 32, seed: 7, ..Default::default() };
//! let volume = TransferBaker::new(&scene, options)?.bake(&NoProgress)?;
//! // The voxel at the box's centre sees the sky through the open front only.
//! let v = volume.field.index(3, 3, 3);
//! let visible = volume.sky_visibility(v);
//! assert!(volume.valid[v] && visible > 0.05 && visible < 0.5);
//! let sky = [constant_sky(1.0); 3];
//! let [direct, red, _, _] = volume.incident(v, &sky);
//! assert!(direct[0] > 0.0 && red[0] > 0.0);
//! # Ok::<(), prt_trace::TraceError>(())
//! ```
#![deny(missing_docs)]

mod bake;
mod brdf_transport;
pub mod bricks;
mod bvh;
pub mod camera;
mod cube;
mod denoise;
mod error;
mod gltf_load;
mod lights_file;
pub mod lit;
pub mod mesh;
mod outdoor;
mod pixel;
mod sampling;
pub mod scene;
pub mod sh;
mod vpl;

pub use bake::{AdaptiveSampling, BakeOptions, BakeStats, TransferBaker, TransferVolume};
pub use bvh::{Hit, RayTracer};
pub use denoise::DenoiseOptions;
pub use error::TraceError;
pub use gltf_load::LoadOptions;
pub use lit::LitVolume;
pub use scene::Scene;
pub use sh::TRANSFER_DIM;

/// The baker's and the ray tracer's details, for tests, benches and callers who need them: the
/// clamped-cosine SH weights, the indirect estimator's mode, the number of independent ray
/// streams per voxel, one 9×9 block of a transfer vector, the BVH's build quality and a
/// brute-force ray query to check the BVH against.
pub mod expert {
    pub use crate::bake::{CLAMPED_COSINE, IndirectMode, REPLICATES, SharedSurfaceCache, block};
    pub use crate::bvh::{BuildQuality, brute_force_closest};
}

/// Many lights: virtual point lights traced from a scene's emitters, or its sun and sky, or read
/// from a lights file, and the pixel × light matrix of a G-buffer lit by them (for prt-manylight).
pub mod manylight {
    pub use crate::lights_file::{
        LightsBudget, LightsFileError, MAX_LIGHTS_LINE_BYTES, format_lights, parse_lights,
        read_lights_file, write_lights_file,
    };
    pub use crate::vpl::{
        DirectionalLight, SunAndUniformSky, Vpl, VplOptions, VplOracle, directional_lights,
        emitted_power, trace_vpls,
    };
}

/// Transport for wavelet relighting: per-pixel rows over a cube map of light (baked, stored,
/// relit frame by frame with prt-wavelet), the half-angle BRDF-editing transport, and the
/// cube-map shadow rays beneath both.
pub mod relight {
    pub use crate::brdf_transport::{
        HalfAngleOptions, HalfAngleTransport, half_angle_bin, trace_half_angle_transport,
    };
    pub use crate::cube::CubeRays;
    pub use crate::pixel::{
        Bounce, MethodRelighter, PixelBakeEstimate, PixelRelighter, PixelTransport,
        PixelTransportBaker, PixelTransportOptions, RelightMethod, RelitFrame, Sparsify,
    };
}
