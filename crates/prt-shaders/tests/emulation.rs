//! A CPU emulation of exactly the shaders' math over the texels `prt_bake::container::write_container`
//! writes: the lighting pass (dequantise, 18-term sums, rgba16f storage) and the per-pixel
//! reconstruction (texel-centre coordinates, trilinear filtering with clamp-to-edge, the
//! coefficients' scale/bias decode, f32 throughout), against the model itself
//! (`MbdModel::eval` then `prt_trace::lit::incident_radiance`) within the quantisation bound.
//!
//! The bound at a point x, per lit value k (c = k / 9, i = k % 9), with φ and ψ the hat
//! weights of the coefficient and basis grids:
//!
//! * a stored value v has error at most e(v): 0 (f32), |v|·2⁻¹¹ + 2⁻²⁵ (f16), half a step of its
//!   channel plus f32 rounding (unorm/snorm);
//! * a lit node value errs by E = Σ_j (e(D_ij) + e(T^c_ij))·|s^c_j| (the lighting map is
//!   linear, with coefficients ±s^c_j) plus its rgba16f rounding, |b̃|·2⁻¹¹ + 2⁻²⁵;
//! * filtering is a convex combination, so the filtered errors are at most ē_l = Σ_m φ_m e(c_ml)
//!   and Ē_lk = Σ_n ψ_n E_nlk, and |c_l| ≤ ĉ_l = Σ φ|c|, |b̃_lk| ≤ b̂_lk = Σ ψ|b̃|;
//! * so |Σ_l c'_l b̃'_lk − Σ_l c_l b̃_lk| ≤ Σ_l ĉ_l Ē_lk + ē_l (b̂_lk + Ē_lk),
//!
//! plus float rounding: 10⁻⁴ of Σ_l max|c_l| max|b̃_lk| over the cell's corners (the texture
//! coordinate of a texel in an atlas of ~100 texels is only good to ~10⁻⁵ texel in f32).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::Vec3;
use half::f16;
use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_bake::container::write_container;
use prt_bake::container::{
    CoefficientLayout, ContainerContents, LayoutConfig, write_container_with,
};
use prt_core::{Aabb, FieldModel};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_sphere::Sky;
use prt_texture::container::{ArrayEntry, Bricks, MANIFEST_FILE, Manifest, atlas_tiles};
use prt_texture::{Encoding, Ktx2Texture, Limits};

const DIM: usize = 324;
const LIT: usize = 27;

fn scratch() -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!(
        "prt-shaders-emulation-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A random rank-`rank` transfer model: coefficients on 6×5×4 nodes, basis on 3×3×2 nodes
/// over a smaller box (as a bake's basis spans the voxel centres).
fn random_model(seed: u64, rank: usize) -> MbdModel<HatGrid, HatGrid> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    };
    let domain = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(3.0, 1.5, 4.0));
    let inner = Aabb::new(Vec3::new(-0.8, 0.1, 2.2), Vec3::new(2.7, 1.4, 3.9));
    let coefficient_kernels = HatGrid::new([6, 5, 4], domain).unwrap();
    let basis_kernels = HatGrid::new([3, 3, 2], inner).unwrap();
    let coefficients = Array2::from_shape_fn((120, rank), |_| 2.0 * next());
    let basis = Array3::from_shape_fn((18, rank, DIM), |_| 0.3 * next());
    MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis).unwrap()
}

/// The `MbdGrid` uniform: domain min, 1 / size (0 on single-node axes), nodes, tiles.
#[derive(Debug, Clone, Copy)]
struct Grid {
    domain_min: [f32; 3],
    inv_size: [f32; 3],
    nodes: [f32; 3],
    tiles: [f32; 3],
}

impl Grid {
    fn new(domain_min: [f32; 3], domain_max: [f32; 3], nodes: [u32; 3], tiles: [u32; 3]) -> Grid {
        Grid {
            domain_min,
            inv_size: [0, 1, 2].map(|a| {
                if nodes[a] >= 2 {
                    1.0 / (domain_max[a] - domain_min[a])
                } else {
                    0.0
                }
            }),
            nodes: nodes.map(|n| n as f32),
            tiles: tiles.map(|t| t as f32),
        }
    }

    /// `mbd_local`.
    fn local(&self, x: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| {
            let t = ((x[a] - self.domain_min[a]) * self.inv_size[a]).clamp(0.0, 1.0);
            t * (self.nodes[a] - 1.0) + 0.5
        })
    }

    /// `mbd_tile`.
    fn tile(&self, g: usize) -> [usize; 3] {
        let (tx, ty) = (self.tiles[0] as usize, self.tiles[1] as usize);
        [g % tx, (g / tx) % ty, g / (tx * ty)]
    }

    /// `mbd_tile_uvw`.
    fn tile_uvw(&self, local: [f32; 3], g: usize) -> [f32; 3] {
        let tile = self.tile(g);
        [0, 1, 2]
            .map(|a| (tile[a] as f32 * self.nodes[a] + local[a]) / (self.nodes[a] * self.tiles[a]))
    }

    fn size(&self) -> [usize; 3] {
        [0, 1, 2].map(|a| (self.nodes[a] * self.tiles[a]) as usize)
    }
}

/// An RGBA 3D texture as the sampler sees it (normalised texel values).
struct Texture {
    size: [usize; 3],
    texels: Vec<f32>,
}

impl Texture {
    fn fetch(&self, p: [usize; 3]) -> [f32; 4] {
        let at = 4 * (p[0] + self.size[0] * (p[1] + self.size[1] * p[2]));
        [0, 1, 2, 3].map(|c| self.texels[at + c])
    }

    /// LINEAR filtering, no mipmaps, CLAMP_TO_EDGE: texel centres at (i + 0.5) / size.
    fn sample(&self, uvw: [f32; 3]) -> [f32; 4] {
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        let mut f = [0.0f32; 3];
        for a in 0..3 {
            let coordinate = uvw[a] * self.size[a] as f32 - 0.5;
            let floor = coordinate.floor();
            f[a] = coordinate - floor;
            let last = self.size[a] as i64 - 1;
            lo[a] = (floor as i64).clamp(0, last) as usize;
            hi[a] = (floor as i64 + 1).clamp(0, last) as usize;
        }
        let mut out = [0.0f32; 4];
        for corner in 0..8 {
            let mut weight = 1.0f32;
            let mut p = [0usize; 3];
            for a in 0..3 {
                let up = corner >> a & 1 == 1;
                weight *= if up { f[a] } else { 1.0 - f[a] };
                p[a] = if up { hi[a] } else { lo[a] };
            }
            let texel = self.fetch(p);
            for c in 0..4 {
                out[c] += weight * texel[c];
            }
        }
        out
    }
}

/// One array of a written container: its manifest entry, its texture and its grid uniform (and,
/// in the bricks layout, its bricks and indirection texture).
struct Stored {
    entry: ArrayEntry,
    texture: Texture,
    grid: Grid,
    bricks: Option<(Bricks, Texture)>,
}

impl Stored {
    fn read(folder: &Path, manifest: &Manifest, name: &str) -> Stored {
        let entry = manifest
            .arrays
            .iter()
            .find(|a| a.name == name)
            .unwrap()
            .clone();
        let ktx2 = Ktx2Texture::read_file(&folder.join(&entry.file), &Limits::small()).unwrap();
        let shape = ktx2.shape();
        let texture = Texture {
            size: [shape.width, shape.height, shape.depth].map(|s| s as usize),
            texels: ktx2.level_f32(0).unwrap(),
        };
        let kernels = &manifest.kernels[name];
        let bricks = entry.bricks.clone().map(|bricks| {
            let ktx2 = Ktx2Texture::read_file(&folder.join(&bricks.indirection), &Limits::small())
                .unwrap();
            let indirection = Texture {
                size: bricks.grid.map(|g| g as usize),
                texels: ktx2.level_f32(0).unwrap(),
            };
            (bricks, indirection)
        });
        let grid = Grid::new(
            kernels.domain_min,
            kernels.domain_max,
            kernels.nodes,
            entry.tile_grid().unwrap_or([1, 1, 1]),
        );
        if bricks.is_none() {
            assert_eq!(texture.size, grid.size(), "{name}: texture = nodes × tiles");
        }
        Stored {
            entry,
            texture,
            grid,
            bricks,
        }
    }

    /// `mbd_coefficient_site` (coefficients_dense.glsl / coefficients_bricks.glsl).
    fn site(&self, x: [f32; 3]) -> [f32; 4] {
        let local = self.grid.local(x);
        let Some((bricks, indirection)) = &self.bricks else {
            return [local[0], local[1], local[2], 1.0];
        };
        let size = bricks.size as f32;
        let p = local.map(|v| v - 0.5);
        let brick = [0, 1, 2].map(|a| (p[a] / size).floor().min(bricks.grid[a] as f32 - 1.0));
        let entry = indirection.fetch(brick.map(|b| b as usize));
        let at = [0, 1, 2].map(|a| (entry[a] * 255.0 + 0.5).floor());
        let texel = [0, 1, 2].map(|a| at[a] * (size + 1.0) + (p[a] - brick[a] * size) + 0.5);
        [texel[0], texel[1], texel[2], entry[3]]
    }

    /// `mbd_coefficient_texel`.
    fn texel(&self, site: [f32; 4], g: usize) -> [f32; 4] {
        let local = [site[0], site[1], site[2]];
        let Some((bricks, _)) = &self.bricks else {
            return self.texture.sample(self.grid.tile_uvw(local, g));
        };
        let texels = bricks.atlas.map(|a| a as f32 * (bricks.size as f32 + 1.0));
        let groups = [1.0, 1.0, self.entry.groups() as f32];
        let offset = [0.0, 0.0, g as f32 * texels[2]];
        let uvw = [0, 1, 2].map(|a| (local[a] + offset[a]) / (texels[a] * groups[a]));
        self.texture.sample(uvw)
    }

    /// Per group: the scale and bias vec4 uniforms (0 beyond the channels).
    fn ranges(&self) -> Vec<([f32; 4], [f32; 4])> {
        (0..self.entry.groups())
            .map(|g| {
                let channel = |k: usize| {
                    let c = 4 * g + k;
                    if c < self.entry.channels {
                        self.entry.range(c)
                    } else {
                        prt_texture::ChannelRange {
                            scale: 0.0,
                            bias: 0.0,
                        }
                    }
                };
                (
                    [0, 1, 2, 3].map(|k| channel(k).scale),
                    [0, 1, 2, 3].map(|k| channel(k).bias),
                )
            })
            .collect()
    }
}

/// The lighting pass (light.glsl / light.wgsl) into an rgba16f atlas.
fn light_pass(basis: &Stored, rank: usize, sky: &Sky) -> (Texture, Grid) {
    let nodes = basis.entry.dims;
    let tiles = atlas_tiles(nodes, 7 * rank);
    // Over the basis grid's nodes and box, 7 tiles per basis vector.
    let lit = Grid {
        tiles: tiles.map(|t| t as f32),
        ..basis.grid
    };
    let ranges = basis.ranges();
    let sky: Vec<f32> = sky.sh.as_flattened().to_vec();
    // mbd_raw
    let raw = |node: [usize; 3], l: usize, d: usize| -> f32 {
        let g = 81 * l + d / 4;
        let tile = basis.grid.tile(g);
        let texel = basis
            .texture
            .fetch([0, 1, 2].map(|a| tile[a] * nodes[a] as usize + node[a]));
        let (scale, bias) = ranges[g];
        bias[d % 4] + scale[d % 4] * texel[d % 4]
    };
    let size = lit.size();
    let mut texels = vec![0.0f32; 4 * size.iter().product::<usize>()];
    for z in 0..size[2] {
        for y in 0..size[1] {
            for x in 0..size[0] {
                let texel = [x, y, z];
                let tile = [0, 1, 2].map(|a| texel[a] / nodes[a] as usize);
                let node = [0, 1, 2].map(|a| texel[a] - tile[a] * nodes[a] as usize);
                let group = tile[0] + tiles[0] as usize * (tile[1] + tiles[1] as usize * tile[2]);
                let (l, r) = (group / 7, group % 7);
                let at = 4 * (x + size[0] * (y + size[1] * z));
                for q in 0..4 {
                    let k = 4 * r + q;
                    let value = if l >= rank || k >= LIT {
                        0.0
                    } else {
                        let (c, i) = (k / 9, k % 9);
                        let mut sum = 0.0f32;
                        for j in 0..9 {
                            let d = raw(node, l, 9 * i + j);
                            let t = raw(node, l, 81 * (c + 1) + 9 * i + j);
                            sum += (d + t) * sky[9 * c + j];
                        }
                        sum
                    };
                    // rgba16float storage
                    texels[at + q] = f16::from_f32(value).to_f32();
                }
            }
        }
    }
    (Texture { size, texels }, lit)
}

/// `mbd_incident_radiance` (reconstruct.glsl / reconstruct.wgsl): 28 values, c·9 + i.
fn reconstruct(
    x: [f32; 3],
    coefficients: &Stored,
    lit: &Texture,
    lit_grid: &Grid,
    rank: usize,
) -> [f32; 28] {
    let ranges = coefficients.ranges();
    let site = coefficients.site(x);
    let lit_local = lit_grid.local(x);
    let mut out = [0.0f32; 28];
    for (g, (scale, bias)) in ranges.iter().enumerate() {
        let texel = coefficients.texel(site, g);
        for k in 0..4 {
            let l = 4 * g + k;
            if l < rank {
                let c = site[3] * (bias[k] + scale[k] * texel[k]);
                for r in 0..7 {
                    let b = lit.sample(lit_grid.tile_uvw(lit_local, 7 * l + r));
                    for q in 0..4 {
                        out[4 * r + q] += c * b[q];
                    }
                }
            }
        }
    }
    out
}

/// Error bound of one stored value (see the module docs).
fn stored_error(encoding: Encoding, value: f32, range: prt_texture::ChannelRange) -> f32 {
    match encoding {
        Encoding::F32 => 0.0,
        Encoding::F16 => value.abs() * 2f32.powi(-11) + 2f32.powi(-25),
        _ => range.half_step(encoding) + 4.0 * f32::EPSILON * (range.bias.abs() + range.scale),
    }
}

/// The bound of the module docs at `x`, per lit value.
fn bound(
    model: &MbdModel<HatGrid, HatGrid>,
    coefficients: &ArrayEntry,
    basis: &ArrayEntry,
    sky: &Sky,
    x: Vec3,
) -> [f32; LIT] {
    let rank = model.rank();
    let encoding = coefficients.encoding;
    let phi = model.coefficient_kernels().eval_local(x).unwrap();
    let psi = model.basis_kernels().eval_local(x).unwrap();
    let (c, b) = (model.coefficients(), model.basis());
    let mut out = [0.0f32; LIT];
    for l in 0..rank {
        let mut c_hat = 0.0f32;
        let mut c_error = 0.0f32;
        let mut c_max = 0.0f32;
        for (&m, &w) in phi.indices().iter().zip(phi.weights()) {
            let v = c[[m as usize, l]];
            c_hat += w * v.abs();
            c_error += w * stored_error(encoding, v, coefficients.range(l));
            c_max = c_max.max(v.abs());
        }
        for k in 0..LIT {
            let (ch, i) = (k / 9, k % 9);
            let s = &sky.sh[ch];
            let (mut b_hat, mut b_error, mut b_max) = (0.0f32, 0.0f32, 0.0f32);
            for (&n, &w) in psi.indices().iter().zip(psi.weights()) {
                let n = n as usize;
                let mut lit = 0.0f32;
                let mut error = 0.0f32;
                for j in 0..9 {
                    let (d, t) = (9 * i + j, 81 * (ch + 1) + 9 * i + j);
                    let (vd, vt) = (b[[n, l, d]], b[[n, l, t]]);
                    lit += (vd + vt) * s[j];
                    let range = |dd: usize| basis.range(l * DIM + dd);
                    error += (stored_error(encoding, vd, range(d))
                        + stored_error(encoding, vt, range(t)))
                        * s[j].abs();
                }
                let storage = (lit.abs() + error) * 2f32.powi(-11) + 2f32.powi(-25);
                b_hat += w * lit.abs();
                b_error += w * (error + storage);
                b_max = b_max.max(lit.abs() + error);
            }
            out[k] += c_hat * b_error + c_error * (b_hat + b_error) + 1e-4 * c_max * b_max;
        }
    }
    out
}

/// Writes `model` with `encoding`, emulates the shaders at `points` (fractions of the
/// coefficient box, extended by 20% on each side) and returns the worst error / bound ratio.
fn worst_ratio(
    model: &MbdModel<HatGrid, HatGrid>,
    encoding: Encoding,
    sky: &Sky,
    points: &[[f32; 3]],
) -> f32 {
    let folder = scratch();
    let valid = vec![true; 8];
    write_container(
        &folder,
        &ContainerContents {
            model,
            grid: [2, 2, 2],
            valid: &valid,
            scene: "emulation",
            lambda: 0.0,
            encoding,
        },
    )
    .unwrap();
    let manifest = Manifest::from_json(
        &std::fs::read(folder.join(MANIFEST_FILE)).unwrap(),
        &Limits::small(),
    )
    .unwrap();
    let coefficients = Stored::read(&folder, &manifest, "coefficients");
    let basis = Stored::read(&folder, &manifest, "basis");
    let rank = model.rank();
    let (lit, lit_grid) = light_pass(&basis, rank, sky);
    let domain = prt_core::SpatialKernels::domain(model.coefficient_kernels());
    let mut worst = 0.0f32;
    let mut transfer = vec![0.0f32; DIM];
    for p in points {
        let x = domain.min + (Vec3::from_array(*p) * 1.4 - 0.2) * domain.size();
        let got = reconstruct(x.to_array(), &coefficients, &lit, &lit_grid, rank);
        model.eval(x, &mut transfer).unwrap();
        let reference = prt_trace::lit::incident_radiance(&transfer, sky);
        let limit = bound(model, &coefficients.entry, &basis.entry, sky, x);
        for k in 0..LIT {
            let error = (got[k] - reference[k / 9][k % 9]).abs();
            worst = worst.max(error / limit[k]);
        }
        assert_eq!(got[27], 0.0, "the 28th lit value is padding");
    }
    let _ = std::fs::remove_dir_all(folder);
    worst
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]

    /// The emulated shaders reproduce the model's lit value within the bound, for every
    /// encoding, ranks that do and do not fill their last texel, and any sky.
    #[test]
    fn the_shaders_math_matches_the_model_within_the_quantisation_bound(
        seed in any::<u64>(),
        rank_is_8 in any::<bool>(),
        degrees in 0.0f32..360.0,
        points in prop::collection::vec(prop::array::uniform3(0.0f32..1.0), 24),
    ) {
        let rank = if rank_is_8 { 8 } else { 3 };
        let model = random_model(seed, rank);
        let sky = Sky::default().rotated_about_y(degrees);
        for encoding in [Encoding::F32, Encoding::F16, Encoding::Unorm16, Encoding::Unorm8] {
            let ratio = worst_ratio(&model, encoding, &sky, &points);
            prop_assert!(ratio <= 1.0, "{encoding:?} rank {rank}: error / bound = {ratio}");
        }
    }
}

/// The bound is tight enough to catch a wrong convention: texel corners instead of centres
/// (node i at texel coordinate i instead of i + 0.5) breaks it.
#[test]
fn a_half_texel_shift_is_caught() {
    let model = random_model(7, 3);
    let sky = Sky::default();
    let points: Vec<[f32; 3]> = (0..16)
        .map(|i| [0.13 + 0.05 * i as f32, 0.37, 0.61].map(|v: f32| v.fract()))
        .collect();
    assert!(worst_ratio(&model, Encoding::F16, &sky, &points) <= 1.0);
    // The same model with every coefficient node moved by half a cell: what sampling with
    // the corner convention would reconstruct.
    let (c_kernels, b_kernels, coefficients, basis) = model.clone().into_parts();
    let domain = prt_core::SpatialKernels::domain(&c_kernels);
    let half_cell = domain.size() / Vec3::new(10.0, 8.0, 6.0);
    let shifted = HatGrid::new(
        c_kernels.nodes(),
        Aabb::new(domain.min + half_cell, domain.max + half_cell),
    )
    .unwrap();
    let wrong = MbdModel::new(shifted, b_kernels, coefficients, basis).unwrap();
    // Textures of the right model, reference of the shifted one.
    let folder = scratch();
    let valid = vec![true; 8];
    write_container(
        &folder,
        &ContainerContents {
            model: &model,
            grid: [2, 2, 2],
            valid: &valid,
            scene: "emulation",
            lambda: 0.0,
            encoding: Encoding::F16,
        },
    )
    .unwrap();
    let manifest = Manifest::from_json(
        &std::fs::read(folder.join(MANIFEST_FILE)).unwrap(),
        &Limits::small(),
    )
    .unwrap();
    let coefficients = Stored::read(&folder, &manifest, "coefficients");
    let basis = Stored::read(&folder, &manifest, "basis");
    let (lit, lit_grid) = light_pass(&basis, 3, &sky);
    let mut worst = 0.0f32;
    let mut transfer = vec![0.0f32; DIM];
    for p in &points {
        let x = domain.min + Vec3::from_array(*p) * domain.size();
        let got = reconstruct(x.to_array(), &coefficients, &lit, &lit_grid, 3);
        wrong.eval(x, &mut transfer).unwrap();
        let reference = prt_trace::lit::incident_radiance(&transfer, &sky);
        let limit = bound(&wrong, &coefficients.entry, &basis.entry, &sky, x);
        for k in 0..LIT {
            worst = worst.max((got[k] - reference[k / 9][k % 9]).abs() / limit[k]);
        }
    }
    let _ = std::fs::remove_dir_all(folder);
    assert!(
        worst > 1.0,
        "a half-cell shift stayed within the bound ({worst})"
    );
}

/// A rank-`rank` model with a coefficient node per voxel of a 13 × 10 × 8 grid (so the live
/// nodes are the valid voxels) whose valid voxels fill two balls, a third of the grid.
fn bricked_case(seed: u64, rank: usize) -> (MbdModel<HatGrid, HatGrid>, [usize; 3], Vec<bool>) {
    let grid = [13, 10, 8];
    let dense = random_model(seed, rank);
    let (_, basis_kernels, _, basis) = dense.into_parts();
    let domain = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(3.0, 1.5, 4.0));
    let nodes: usize = grid.iter().product();
    let mut state = seed | 1;
    let coefficients = Array2::from_shape_fn((nodes, rank), |_| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 * 4.0 - 2.0
    });
    let kernels = HatGrid::new(grid, domain).unwrap();
    let model = MbdModel::new(kernels, basis_kernels, coefficients, basis).unwrap();
    let valid = (0..nodes)
        .map(|v| {
            let p = [v % 13, v / 13 % 10, v / 130].map(|i| i as f32);
            let d2 = |c: [f32; 3]| (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f32>();
            d2([2.0, 2.0, 2.0]) < 7.0 || d2([10.0, 7.0, 5.0]) < 6.0
        })
        .collect();
    (model, grid, valid)
}

/// The coefficients and basis of `model` written in `layout` (bricks of `brick_size` cells).
fn write_layout(
    model: &MbdModel<HatGrid, HatGrid>,
    grid: [usize; 3],
    valid: &[bool],
    encoding: Encoding,
    layout: CoefficientLayout,
    brick_size: u32,
) -> (Stored, Stored) {
    let folder = scratch();
    write_container_with(
        &folder,
        &ContainerContents {
            model,
            grid,
            valid,
            scene: "emulation",
            lambda: 0.0,
            encoding,
        },
        &LayoutConfig {
            layout,
            brick_size,
            live_nodes: None,
        },
    )
    .unwrap();
    let manifest = Manifest::from_json(
        &std::fs::read(folder.join(MANIFEST_FILE)).unwrap(),
        &Limits::small(),
    )
    .unwrap();
    let stored = (
        Stored::read(&folder, &manifest, "coefficients"),
        Stored::read(&folder, &manifest, "basis"),
    );
    let _ = std::fs::remove_dir_all(folder);
    stored
}

/// Whether the cell holding node coordinate `p` has a live (valid) corner: where the bricks
/// must reproduce the dense volume.
fn cell_is_live(p: [f32; 3], grid: [usize; 3], valid: &[bool]) -> bool {
    let lo = [0, 1, 2].map(|a| (p[a].floor() as usize).min(grid[a] - 1));
    (0..8).any(|corner: usize| {
        let n = [0, 1, 2].map(|a| (lo[a] + (corner >> a & 1)).min(grid[a] - 1));
        valid[n[0] + grid[0] * (n[1] + grid[1] * n[2])]
    })
}

fn world(model: &MbdModel<HatGrid, HatGrid>, p: [f32; 3]) -> Vec3 {
    let kernels = model.coefficient_kernels();
    let domain = prt_core::SpatialKernels::domain(kernels);
    let steps = Vec3::from_array(kernels.nodes().map(|n| (n - 1) as f32));
    domain.min + Vec3::from_array(p) / steps * domain.size()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    /// Through the indirection, the bricked coefficient volume reproduces the model within the
    /// quantisation bound wherever a cell has a valid corner, as the dense one does.
    #[test]
    fn the_bricks_shaders_match_the_model_on_live_cells(
        seed in any::<u64>(),
        rank_is_8 in any::<bool>(),
        brick_size in 2u32..5,
        points in prop::collection::vec(prop::array::uniform3(0.0f32..1.0), 160),
    ) {
        let rank = if rank_is_8 { 8 } else { 3 };
        let (model, grid, valid) = bricked_case(seed, rank);
        let sky = Sky::default();
        for encoding in [Encoding::F16, Encoding::Unorm8] {
            let (coefficients, basis) =
                write_layout(&model, grid, &valid, encoding, CoefficientLayout::Bricks, brick_size);
            let (dense, _) =
                write_layout(&model, grid, &valid, encoding, CoefficientLayout::Dense, brick_size);
            prop_assert!(coefficients.bricks.is_some());
            let (lit, lit_grid) = light_pass(&basis, rank, &sky);
            let mut transfer = vec![0.0f32; DIM];
            let mut checked = 0;
            for unit in &points {
                let p = [0, 1, 2].map(|a| unit[a] * (grid[a] - 1) as f32);
                if !cell_is_live(p, grid, &valid) {
                    continue;
                }
                checked += 1;
                let x = world(&model, p);
                let got = reconstruct(x.to_array(), &coefficients, &lit, &lit_grid, rank);
                let dense = reconstruct(x.to_array(), &dense, &lit, &lit_grid, rank);
                model.eval(x, &mut transfer).unwrap();
                let reference = prt_trace::lit::incident_radiance(&transfer, &sky);
                let limit = bound(&model, &coefficients.entry, &basis.entry, &sky, x);
                for k in 0..LIT {
                    let error = (got[k] - reference[k / 9][k % 9]).abs();
                    prop_assert!(error <= limit[k], "{encoding:?}: {error} > {} at {p:?}", limit[k]);
                    prop_assert!((got[k] - dense[k]).abs() <= 1e-4 * (1.0 + dense[k].abs()));
                }
            }
            prop_assert!(checked > 20, "only {checked} points in live cells");
        }
    }
}

/// Filtering is seamless across brick borders: the jump of the reconstruction across a border
/// plane (±10⁻³ cell) is what the dense volume's is at the same points (ratio ≈ 1), where a
/// brick without its apron would clamp to its last texel and jump.
#[test]
fn brick_borders_are_seamless() {
    let (model, grid, valid) = bricked_case(11, 3);
    let sky = Sky::default();
    let size = 3u32;
    let write = |layout| write_layout(&model, grid, &valid, Encoding::F16, layout, size);
    let (bricks, basis) = write(CoefficientLayout::Bricks);
    let (dense, _) = write(CoefficientLayout::Dense);
    let (lit, lit_grid) = light_pass(&basis, 3, &sky);
    let eval = |stored: &Stored, p: [f32; 3]| {
        reconstruct(world(&model, p).to_array(), stored, &lit, &lit_grid, 3)
    };
    let (mut jump_bricks, mut jump_dense, mut jump_value) = (0.0f64, 0.0f64, 0.0f64);
    let mut crossings = 0;
    for axis in 0..3 {
        for border in (size as usize..grid[axis] - 1).step_by(size as usize) {
            for i in 0..40 {
                let mut p = [0.37, 0.61, 0.23]
                    .map(|f: f32| ((f + 0.137 * i as f32).fract() * 0.999 + 0.0005) * 1.0);
                p = [0, 1, 2].map(|a| p[a] * (grid[a] - 1) as f32);
                p[axis] = border as f32;
                let (mut before, mut after) = (p, p);
                before[axis] -= 1e-3;
                after[axis] += 1e-3;
                if !(cell_is_live(before, grid, &valid) && cell_is_live(after, grid, &valid)) {
                    continue;
                }
                crossings += 1;
                let (b0, b1) = (eval(&bricks, before), eval(&bricks, after));
                let (d0, d1) = (eval(&dense, before), eval(&dense, after));
                for k in 0..LIT {
                    jump_bricks += f64::from((b1[k] - b0[k]).abs());
                    jump_dense += f64::from((d1[k] - d0[k]).abs());
                    jump_value += f64::from(d0[k].abs());
                }
            }
        }
    }
    let ratio = jump_bricks / jump_dense;
    println!(
        "{crossings} border crossings: jump bricks / dense = {ratio:.4}, mean jump / mean value = {:.2e}",
        jump_bricks / jump_value
    );
    assert!(crossings > 50, "{crossings} crossings");
    assert!((0.9..=1.1).contains(&ratio), "seam ratio {ratio}");
}
