//! The progressive bake: passes of samples per texel, splatted into per-texel encoders.

use std::f64::consts::TAU;

use glam::Vec3;
use ndarray::{Array1, Array2};
use prt_core::{Progress, SphericalBasis};
use prt_plsq::{BatchEncoder, EncoderConfig};
use prt_sphere::SgBasis;
use prt_trace::{RayTracer, Scene};
use rayon::prelude::*;

use crate::basis::{cosine_weights, gram_inverse};
use crate::punctual::PunctualDirect;
use crate::trace::{Lighting, MAX_BOUNCES, Sample, Transport};
use crate::{Atlas, Encoder, LightmapBasis, LightmapError, Seams, TexelMap};

/// Knobs of [`bake_lightmap`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightmapConfig {
    /// What each texel stores.
    pub basis: LightmapBasis,
    /// How samples become coefficients (non-negative PLSQ by default, as in the paper's
    /// Figure 1).
    pub encoder: Encoder,
    /// Samples per texel.
    pub samples: u32,
    /// Samples per texel per pass; the state is consistent (every texel has the same count)
    /// after each pass.
    pub pass_samples: u32,
    /// A snapshot is handed out after the first pass at or past every multiple of this many
    /// samples (0: only the final one).
    pub snapshot_every: u32,
    /// Diffuse bounces after the surface a texel ray hits (0: emitters and sky seen directly,
    /// no reflected light).
    pub bounces: u32,
    /// The light; `None` for [`Lighting::for_scene`].
    pub lighting: Option<Lighting>,
    /// Roughton's hemisphere rule: each sample is followed by a zero-radiance sample in the
    /// opposite direction, so the fit vanishes below the surface instead of being unconstrained.
    pub hemisphere_rule: bool,
    /// Each texel scrambles its Sobol' sequence differently (the paper's Figure 5: correlated
    /// sequences across texels give structured error).
    pub decorrelated: bool,
    /// Rings of empty texels filled around charts.
    pub dilation: u32,
    /// Average the texels on both sides of UV seams on smooth surfaces.
    pub stitch_seams: bool,
    /// Seed of every random choice.
    pub seed: u64,
    /// Refuse a bake whose estimated memory exceeds this many bytes.
    pub max_memory_bytes: Option<u64>,
}

impl Default for LightmapConfig {
    fn default() -> Self {
        Self {
            basis: LightmapBasis::Sg { lobes: 9 },
            encoder: Encoder::PlsqNonNegative,
            samples: 256,
            pass_samples: 16,
            snapshot_every: 0,
            bounces: 2,
            lighting: None,
            hemisphere_rule: true,
            decorrelated: true,
            dilation: 2,
            stitch_seams: true,
            seed: 1,
            max_memory_bytes: None,
        }
    }
}

/// A lightmap: per texel, the coefficients of the incident radiance and the irradiance.
#[derive(Debug, Clone, PartialEq)]
pub struct Lightmap {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// The basis of `coefficients`.
    pub basis: LightmapBasis,
    /// One RGB image (`width · height · 3`, row-major, top row first) per basis function:
    /// the coefficients of incident radiance in the texel's tangent frame. Empty for
    /// [`LightmapBasis::Irradiance`].
    pub coefficients: Vec<Vec<f32>>,
    /// Irradiance at the texel's normal (RGB image): the cosine integral of the fit, or the
    /// Monte Carlo estimate for [`LightmapBasis::Irradiance`]. A diffuse surface's outgoing
    /// radiance is `albedo / π` times it.
    pub irradiance: Vec<f32>,
    /// Texels with a surface point (before dilation).
    pub covered: Vec<bool>,
    /// Samples per texel behind the values.
    pub samples_per_texel: u32,
}

/// What [`bake_lightmap`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct LightmapBake {
    /// The last consistent lightmap.
    pub lightmap: Lightmap,
    /// Whether the bake stopped early through the `Progress` handle (the lightmap then holds
    /// the last completed pass).
    pub cancelled: bool,
    /// Texels with a surface point.
    pub texels: usize,
    /// Texels whose centre two triangles claim (overlapping UVs).
    pub overlapping_texels: usize,
    /// Texel pairs stitched across seams.
    pub seam_pairs: usize,
    /// Estimated peak memory, bytes.
    pub estimated_bytes: u64,
}

/// Bytes a bake of `atlas` over `triangles` triangles will use at most (texel map, encoder
/// state, one pass of samples, the output images, the ray tracer).
pub fn estimate_memory(atlas: &Atlas, triangles: usize, config: &LightmapConfig) -> u64 {
    let texels = u64::from(atlas.width) * u64::from(atlas.height);
    let k = config.basis.len() as u64;
    let state_per_texel = match (config.basis, config.encoder) {
        (LightmapBasis::Irradiance, _) => 4 * 8,
        (_, Encoder::Plsq | Encoder::PlsqNonNegative) => (4 * k + 1) * 4,
        (_, Encoder::LeastSquares | Encoder::Nnls) => (k * (k + 1) / 2 + 3 * k + 1) * 8,
        (_, Encoder::Naive) => (3 * k + 1) * 8,
    };
    let sample_bytes = 28 * u64::from(config.pass_samples.max(1));
    let map = 40 + 8;
    let output = 2 * (k + 1) * 3 * 4 + 1;
    texels * (state_per_texel + sample_bytes + map + output) + triangles as u64 * 160
}

/// Per-texel state of the encoders.
enum State<'b> {
    Sg(BatchEncoder<'b, SgBasis>),
    Dyn(BatchEncoder<'b, dyn SphericalBasis>),
    /// f64 sums per texel, `stride` values each: LS/NNLS `[Gram upper | rhs K×3 | W]`, naive
    /// `[rhs K×3 | W]`, irradiance `[E×3 | W]`.
    Sums {
        stride: usize,
        sums: Vec<f64>,
    },
}

/// Bakes the lightmap of `scene` (whose triangles `atlas` was made for): per texel, samples of
/// incident radiance over the hemisphere around its normal, path traced ([`Lighting`]: sky,
/// sun, emitters, punctual lights; `bounces` diffuse bounces with next-event estimation; the
/// punctual lights a texel sees directly are deltas, added to its fit in closed form),
/// splatted in passes into the texel's encoder (progressive least squares: Roughton,
/// "Progressive Least-Squares Encoding for Linear Bases", JCGT 9(1), 2020).
///
/// After each pass every texel has the same number of samples; `on_snapshot` receives the
/// lightmap (dilated and stitched) at the intervals of `snapshot_every` and at the end.
/// Cancellation through `progress` stops inside a pass and returns the last completed pass.
/// Texel `t`'s sample `k` is a function of `(seed, t, k)`, and sums run in sample order, so a
/// seed gives bit-identical lightmaps on any thread count.
///
/// Errors: an atlas for other triangles, a scene without triangles, knobs out of range, an
/// estimate over `max_memory_bytes`, cancellation before the first pass.
pub fn bake_lightmap(
    scene: &Scene,
    atlas: &Atlas,
    config: &LightmapConfig,
    progress: &dyn Progress,
    on_snapshot: &mut dyn FnMut(&Lightmap),
) -> Result<LightmapBake, LightmapError> {
    let triangles = scene.triangles();
    if triangles.is_empty() {
        return Err(LightmapError::EmptyScene);
    }
    if atlas.uvs.len() != triangles.len() {
        return Err(LightmapError::invalid(
            "atlas",
            format!(
                "{} UV triangles for a scene of {}",
                atlas.uvs.len(),
                triangles.len()
            ),
        ));
    }
    if config.samples == 0 || config.pass_samples == 0 {
        return Err(LightmapError::invalid(
            "samples",
            "samples and samples per pass must be >= 1",
        ));
    }
    if config.bounces > MAX_BOUNCES {
        return Err(LightmapError::invalid(
            "bounces",
            format!("{} (at most {MAX_BOUNCES})", config.bounces),
        ));
    }
    let estimated_bytes = estimate_memory(atlas, triangles.len(), config);
    if let Some(budget) = config.max_memory_bytes
        && estimated_bytes > budget
    {
        return Err(LightmapError::MemoryBudget {
            needed: estimated_bytes,
            budget,
        });
    }
    let map = TexelMap::new(triangles, atlas);
    let seams = if config.stitch_seams {
        Seams::new(triangles, atlas, &map)
    } else {
        Seams::default()
    };
    let tracer = RayTracer::new(triangles);
    let lighting = config
        .lighting
        .unwrap_or_else(|| Lighting::for_scene(scene));
    let transport = Transport::new(scene, &tracer, lighting, config.bounces);
    // Texel points are pulled towards their triangle's centre by ten ray offsets (at most half
    // way): rays from a point on an edge of a concave corner otherwise start on the adjacent
    // face or slip through the corner.
    let active: Vec<(usize, Vec3, Vec3)> = map
        .texels
        .iter()
        .enumerate()
        .filter_map(|(i, t)| {
            t.map(|t| {
                let tri = triangles[t.triangle as usize];
                let to_centre = (tri[0] + tri[1] + tri[2]) / 3.0 - t.position;
                let pull = to_centre.normalize_or_zero()
                    * (0.5 * to_centre.length()).min(10.0 * transport.eps());
                (i, t.position + pull, t.normal)
            })
        })
        .collect();
    if active.is_empty() {
        return Err(LightmapError::invalid(
            "atlas",
            "no texel lies on a triangle",
        ));
    }
    let functions = config.basis.functions()?;
    let sg_basis = match config.basis {
        LightmapBasis::Sg { lobes } => {
            let (axes, sharpness) = LightmapBasis::sg_lobes(lobes);
            Some(SgBasis::new(
                axes,
                vec![sharpness; lobes],
                config.basis.label(),
            )?)
        }
        _ => None,
    };
    let k = config.basis.len();
    let plsq_config = EncoderConfig {
        non_negative: config.encoder == Encoder::PlsqNonNegative,
        hemisphere: config.hemisphere_rule,
        ..EncoderConfig::paper()
    };
    let mut state = match (functions.as_deref(), config.encoder) {
        (None, _) => State::Sums {
            stride: 4,
            sums: vec![0.0; active.len() * 4],
        },
        (Some(f), Encoder::Plsq | Encoder::PlsqNonNegative) => match &sg_basis {
            Some(sg) => State::Sg(BatchEncoder::new_sg(sg, 3, active.len(), plsq_config)?),
            None => State::Dyn(BatchEncoder::new(f, 3, active.len(), plsq_config)?),
        },
        (Some(_), Encoder::LeastSquares | Encoder::Nnls) => {
            let stride = k * (k + 1) / 2 + 3 * k + 1;
            State::Sums {
                stride,
                sums: vec![0.0; active.len() * stride],
            }
        }
        (Some(_), Encoder::Naive) => State::Sums {
            stride: 3 * k + 1,
            sums: vec![0.0; active.len() * (3 * k + 1)],
        },
    };
    let punctual = PunctualDirect::new(
        &transport,
        functions.as_deref(),
        config.encoder,
        config.hemisphere_rule,
    )?;
    let solver = Solver {
        punctual,
        basis: functions.as_deref(),
        encoder: config.encoder,
        k,
        cosine: functions.as_deref().map(cosine_weights).unwrap_or_default(),
        gram_inverse: match (functions.as_deref(), config.encoder) {
            (Some(b), Encoder::Naive) => Some(gram_inverse(b)?),
            _ => None,
        },
    };
    let snapshot = |state: &State<'_>, done: u32| -> Result<Lightmap, LightmapError> {
        solver.snapshot(state, &active, &map, &seams, config, done)
    };
    progress.set_len(active.len() as u64 * u64::from(config.samples));
    let mut done = 0u32;
    let mut last: Option<Lightmap> = None;
    let mut cancelled = false;
    while done < config.samples {
        let n = config.pass_samples.min(config.samples - done);
        let Some(samples) = trace_pass(&transport, &active, config, done, n, progress) else {
            cancelled = true;
            break;
        };
        solver.splat(&mut state, &samples, n as usize, config.hemisphere_rule)?;
        let before = done;
        done += n;
        let crossed = config.snapshot_every > 0
            && done / config.snapshot_every > before / config.snapshot_every;
        if crossed || done == config.samples {
            let lightmap = snapshot(&state, done)?;
            on_snapshot(&lightmap);
            last = Some(lightmap);
        }
    }
    if done == 0 {
        return Err(LightmapError::Cancelled);
    }
    let lightmap = match last {
        Some(l) if l.samples_per_texel == done => l,
        _ => snapshot(&state, done)?,
    };
    Ok(LightmapBake {
        lightmap,
        cancelled,
        texels: active.len(),
        overlapping_texels: map.overlapping,
        seam_pairs: seams.pairs.len(),
        estimated_bytes,
    })
}

fn hash(seed: u64, stream: u64, index: u64) -> u32 {
    let mut z = seed
        .wrapping_add(stream.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add(index.wrapping_mul(0xD1B5_4A32_D192_ED03));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) as u32
}

/// Samples `first..first + n` of every active texel, texel-major; `None` when cancelled.
fn trace_pass(
    transport: &Transport<'_>,
    active: &[(usize, Vec3, Vec3)],
    config: &LightmapConfig,
    first: u32,
    n: u32,
    progress: &dyn Progress,
) -> Option<Vec<Sample>> {
    const CHUNK: usize = 64;
    let chunks: Option<Vec<Vec<Sample>>> = active
        .par_chunks(CHUNK)
        .map(|chunk| {
            if progress.is_cancelled() {
                return None;
            }
            let mut out = Vec::with_capacity(chunk.len() * n as usize);
            for &(texel, position, normal) in chunk {
                let stream = if config.decorrelated {
                    texel as u64 + 1
                } else {
                    0
                };
                for k in first..first + n {
                    // Owen-scrambled Sobol' (2^16 points per scramble; the next 2^16 rescramble).
                    let scramble = hash(config.seed, stream, u64::from(k >> 16));
                    let index = k & 0xffff;
                    let u = |dim: u32| sobol_burley::sample(index, dim, scramble);
                    out.push(transport.sample(position, normal, &u));
                }
            }
            progress.inc((chunk.len() * n as usize) as u64);
            Some(out)
        })
        .collect();
    chunks.map(|c| c.into_iter().flatten().collect())
}

struct Solver<'b> {
    /// The sun and the point, spot and directional lights seen directly from texels, added to
    /// every snapshot.
    punctual: Option<PunctualDirect<'b>>,
    basis: Option<&'b dyn SphericalBasis>,
    encoder: Encoder,
    k: usize,
    cosine: Vec<f32>,
    gram_inverse: Option<Array2<f64>>,
}

impl Solver<'_> {
    /// Adds a pass (`n` samples per texel, texel-major) to the state.
    fn splat(
        &self,
        state: &mut State<'_>,
        samples: &[Sample],
        n: usize,
        hemisphere: bool,
    ) -> Result<(), LightmapError> {
        match state {
            State::Sg(_) | State::Dyn(_) => {
                let dirs: Vec<Vec3> = samples.iter().map(|s| s.local).collect();
                let values: Vec<f32> = samples.iter().flat_map(|s| s.radiance.to_array()).collect();
                match state {
                    State::Sg(enc) => enc.add_sample_runs(n, &dirs, &values, None)?,
                    State::Dyn(enc) => enc.add_sample_runs(n, &dirs, &values, None)?,
                    State::Sums { .. } => {}
                }
            }
            State::Sums { stride, sums } => {
                let k = self.k;
                let stride = *stride;
                sums.par_chunks_mut(stride)
                    .zip(samples.par_chunks(n))
                    .for_each_init(
                        || vec![0.0f32; k],
                        |b, (acc, texel_samples)| {
                            for s in texel_samples {
                                let l = s.radiance.as_dvec3().to_array();
                                let Some(basis) = self.basis else {
                                    for c in 0..3 {
                                        acc[c] += l[c] * f64::from(s.local.y);
                                    }
                                    acc[3] += 1.0;
                                    continue;
                                };
                                let gram_len = if self.gram_inverse.is_some() {
                                    0
                                } else {
                                    k * (k + 1) / 2
                                };
                                let mirrors: &[f32] = if hemisphere && gram_len > 0 {
                                    &[1.0, -1.0]
                                } else {
                                    &[1.0]
                                };
                                for &sign in mirrors {
                                    basis.eval(s.local * sign, b);
                                    if gram_len > 0 {
                                        let mut at = 0;
                                        for i in 0..k {
                                            for j in i..k {
                                                acc[at] += f64::from(b[i]) * f64::from(b[j]);
                                                at += 1;
                                            }
                                        }
                                    }
                                    if sign > 0.0 {
                                        for i in 0..k {
                                            for c in 0..3 {
                                                acc[gram_len + 3 * i + c] += f64::from(b[i]) * l[c];
                                            }
                                        }
                                    }
                                }
                                acc[gram_len + 3 * k] += 1.0;
                            }
                        },
                    );
            }
        }
        Ok(())
    }

    /// Coefficients (`k × 3`) and irradiance of texel `e` of the state.
    fn texel(&self, state: &State<'_>, e: usize) -> Result<(Vec<f32>, [f32; 3]), LightmapError> {
        let k = self.k;
        let coeffs: Vec<f32> = match state {
            State::Sg(enc) => enc.coefficients(e).unwrap_or_default(),
            State::Dyn(enc) => enc.coefficients(e).unwrap_or_default(),
            State::Sums { stride, sums } => {
                let acc = &sums[e * stride..(e + 1) * stride];
                let w = acc[stride - 1];
                if w <= 0.0 {
                    return Ok((vec![0.0; 3 * k], [0.0; 3]));
                }
                if self.basis.is_none() {
                    let e = [0, 1, 2].map(|c| (TAU * acc[c] / w) as f32);
                    return Ok((Vec::new(), e));
                }
                if let Some(inv) = &self.gram_inverse {
                    let rhs = Array2::from_shape_fn((k, 3), |(i, c)| TAU * acc[3 * i + c] / w);
                    inv.dot(&rhs).iter().map(|&v| v as f32).collect()
                } else {
                    let gram_len = k * (k + 1) / 2;
                    let mut g = Array2::<f64>::zeros((k, k));
                    let mut at = 0;
                    for i in 0..k {
                        for j in i..k {
                            g[[i, j]] = acc[at] / w;
                            g[[j, i]] = acc[at] / w;
                            at += 1;
                        }
                    }
                    let rhs = Array2::from_shape_fn((k, 3), |(i, c)| acc[gram_len + 3 * i + c] / w);
                    // A ridge of 1e-9 of the mean diagonal: fewer samples than functions leave
                    // the normal equations singular.
                    let ridge = 1e-9 * g.diag().sum() / k as f64 + 1e-300;
                    let mut out = vec![0.0f32; 3 * k];
                    if self.encoder == Encoder::Nnls {
                        let mut ridged = g.clone();
                        ridged.diag_mut().mapv_inplace(|d| d + ridge);
                        for c in 0..3 {
                            let col: Array1<f64> = rhs.column(c).to_owned();
                            let sol =
                                prt_linalg::nnls_gram(ridged.view(), col.view()).map_err(|e| {
                                    LightmapError::invalid("texel normal equations", e.to_string())
                                })?;
                            for i in 0..k {
                                out[3 * i + c] = sol.x[i] as f32;
                            }
                        }
                    } else {
                        let x = prt_linalg::cholesky_solve(g.view(), rhs.view(), ridge).map_err(
                            |e| LightmapError::invalid("texel normal equations", e.to_string()),
                        )?;
                        for (o, v) in out.iter_mut().zip(x.iter()) {
                            *o = *v as f32;
                        }
                    }
                    out
                }
            }
        };
        let mut e = [0.0f32; 3];
        for i in 0..k {
            for c in 0..3 {
                e[c] += self.cosine[i] * coeffs[3 * i + c];
            }
        }
        Ok((coeffs, e))
    }

    fn snapshot(
        &self,
        state: &State<'_>,
        active: &[(usize, Vec3, Vec3)],
        map: &TexelMap,
        seams: &Seams,
        config: &LightmapConfig,
        done: u32,
    ) -> Result<Lightmap, LightmapError> {
        let (w, h) = (map.width as usize, map.height as usize);
        let k = self.k;
        let texels: Vec<(Vec<f32>, [f32; 3])> = (0..active.len())
            .into_par_iter()
            .map(|e| {
                let (mut coeffs, mut irradiance) = self.texel(state, e)?;
                if let Some(p) = &self.punctual {
                    let (_, position, normal) = active[e];
                    p.add(position, normal, &self.cosine, &mut coeffs, &mut irradiance)?;
                }
                Ok::<_, LightmapError>((coeffs, irradiance))
            })
            .collect::<Result<_, _>>()?;
        let mut layers = vec![vec![0.0f32; w * h * 3]; k + 1];
        let mut covered = vec![false; w * h];
        for (&(i, _, _), (coeffs, e)) in active.iter().zip(&texels) {
            covered[i] = true;
            for f in 0..k {
                layers[f][3 * i..3 * i + 3].copy_from_slice(&coeffs[3 * f..3 * f + 3]);
            }
            layers[k][3 * i..3 * i + 3].copy_from_slice(e);
        }
        seams.stitch(&mut layers, 3, 2);
        let mut filled = covered.clone();
        crate::dilate_texels(&mut layers, 3, &mut filled, w, config.dilation as usize);
        let irradiance = layers.pop().unwrap_or_default();
        Ok(Lightmap {
            width: map.width,
            height: map.height,
            basis: config.basis,
            coefficients: layers,
            irradiance,
            covered,
            samples_per_texel: done,
        })
    }
}
