//! Overbeck's thesis §7.2 (changing view with an in-out BRDF factorisation) and §7.3
//! (incremental clustered PCA) on a traced scene under a rotating environment map.
//!
//! ```text
//! cargo run -p prt-benches --bin wavelet_view_cpca -- --scene cornell --map probulator_grace
//! ```
//!
//! The view is the glTF's first camera, else prt-render's framing of the scene; the camera
//! path slides the eye sideways by ±15% of the distance to the view's centre, looking at it.
//! Surface points are the vertices of the triangles that the camera path sees, each triangle
//! tessellated to a lattice of spacing `--spacing` × the distance to the centre of the view (the
//! Cornell box's triangles are a wall each; Sponza's are mostly smaller than one spacing); a
//! pixel interpolates its sub-triangle's three points barycentrically. Each point traces one
//! shadow ray per texel of a `6 × size × size` lighting cube map (`prt_trace::relight::CubeRays`, one
//! sample per texel, so the un-factorised reference below sees exactly the same visibility).
//!
//! §7.2: a Blinn-Phong lobe (`--exponent`) factored into `--brdf-terms` terms
//! ([`BrdfFactorisation`]); per point `K` rows `V g_k cos Ω` Haar-transformed, `--keep` entries
//! per row kept and quantised ([`SparseTransport`]); the `K × 3` lit terms per point come from
//! the incremental [`Relighter`]; a pixel is `Σ_k σ_k h_k(ωo) Σ_v b_v (T_k · L)_v`. Errors are
//! image RMSE relative to the RMS of the reference: against the un-factorised BRDF
//! (`Σ_t V cos Ω ρ(ω_t, ωo) L_t` with the pixel's own `ωo`) and against the K-term product with
//! the exact lighting.
//!
//! §7.3: the points' diffuse rows (`V cos Ω / π`, Haar), compressed by prt-mbd's clustered PCA
//! (`--clusters` × `--basis`), relit by [`CpcaRelighter`]; per-point radiance error relative to
//! the uncompressed product with the exact lighting, and multiply-adds per frame.

use std::time::Instant;

use clap::Parser;
use glam::{Mat3, Vec3};
use ndarray::Array2;
use prt_benches::{Table, load_envmap, load_scene, relative_rms};
use prt_core::{Aabb, CoreError, GridField, MatrixOracle, NoProgress};
use prt_mbd::ClusteredPca;
use prt_sphere::envmap::cube_to_direction;
use prt_trace::RayTracer;
use prt_trace::camera::PinholeView;
use prt_trace::relight::CubeRays;
use prt_wavelet::sequence::Rotation;
use prt_wavelet::{
    Approximator, BandStrategy, BrdfFactorisation, CpcaModel, CpcaRelighter, CubemapHaar,
    CubemapLayout, FactorisationConfig, PointUpdate, Policy, Relighter, SparseTransport, Weighting,
    local_frame,
};
use rayon::prelude::*;

#[derive(Parser, Debug)]
struct Args {
    /// cornell or sponza.
    #[arg(long, default_value = "cornell")]
    scene: String,
    /// Environment map in ../shared/envmaps.
    #[arg(long, default_value = "probulator_grace")]
    map: String,
    /// Lighting cube face side.
    #[arg(long, default_value_t = 16)]
    size: usize,
    /// Image side in pixels.
    #[arg(long, default_value_t = 64)]
    image: usize,
    /// Lattice spacing as a fraction of the distance to the view's centre.
    #[arg(long, default_value_t = 0.04)]
    spacing: f32,
    /// Blinn-Phong exponent of the glossy lobe.
    #[arg(long, default_value_t = 20.0)]
    exponent: f32,
    /// BRDF terms K.
    #[arg(long, default_value_t = 6)]
    brdf_terms: usize,
    /// Paraboloid grid side of the BRDF table.
    #[arg(long, default_value_t = 32)]
    brdf_grid: usize,
    /// Wavelet coefficients kept per transport row (§7.2).
    #[arg(long, default_value_t = 256)]
    keep: usize,
    /// Lighting terms per frame.
    #[arg(long, default_value_t = 30)]
    terms: usize,
    /// Rotation speed, degrees per frame.
    #[arg(long, default_value_t = 2.0)]
    speed: f32,
    /// Frame at which the rotation stops.
    #[arg(long, default_value_t = 20)]
    stop: usize,
    /// Frames.
    #[arg(long, default_value_t = 32)]
    frames: usize,
    /// Views of the camera path.
    #[arg(long, default_value_t = 8)]
    views: usize,
    /// CPCA clusters C.
    #[arg(long, default_value_t = 16)]
    clusters: usize,
    /// CPCA basis vectors per cluster S.
    #[arg(long, default_value_t = 16)]
    basis: usize,
    /// Refuse to trace more points than this.
    #[arg(long, default_value_t = 40_000)]
    max_points: usize,
}

/// A triangle's lattice: `level` segments per edge, points from `first`, the unit normal
/// facing the first camera.
#[derive(Clone, Copy)]
struct Lattice {
    level: usize,
    first: usize,
    normal: Vec3,
}

/// What a pixel sees: three points with barycentric weights, and the direction to the eye
/// in the surface's local frame.
#[derive(Clone, Copy)]
struct PixelShade {
    points: [(u32, f32); 3],
    wo: Vec3,
    frame: Mat3,
}

fn lattice_index(level: usize, i: usize, j: usize) -> usize {
    j * (level + 1) - j * j.saturating_sub(1) / 2 + i
}

fn blinn(exponent: f32) -> impl Fn(Vec3, Vec3) -> f32 + Sync {
    let norm = (exponent + 2.0) / (2.0 * std::f32::consts::PI);
    move |wi: Vec3, wo: Vec3| {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        let h = (wi + wo).normalize_or_zero();
        norm * h.z.max(0.0).powf(exponent)
    }
}

/// A transport row's kept (coefficient, value) pairs.
type SparseRow = Vec<(u32, f32)>;

/// Rows stored sparse, served dense.
struct SparseRows {
    cols: usize,
    rows: Vec<SparseRow>,
}

impl MatrixOracle for SparseRows {
    fn rows(&self) -> usize {
        self.rows.len()
    }
    fn cols(&self) -> usize {
        self.cols
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.fill(0.0);
        for &(j, v) in &self.rows[i] {
            out[j as usize] = v;
        }
        Ok(())
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        for (o, row) in out.iter_mut().zip(&self.rows) {
            *o = row.iter().find(|e| e.0 as usize == j).map_or(0.0, |e| e.1);
        }
        Ok(())
    }
    fn elements_evaluated(&self) -> u64 {
        0
    }
}

fn main() {
    let args = Args::parse();
    let scene = load_scene(&args.scene).unwrap_or_else(|e| panic!("{e}"));
    let map = load_envmap(&args.map).unwrap_or_else(|e| panic!("{e}"));
    let tracer = RayTracer::new(scene.triangles());
    let bounds = scene.bounds().expect("non-empty scene");
    let offset = 1e-4 * (bounds.max - bounds.min).length();
    let named = prt_render::views(&scene);
    // The glTF's camera where there is one (Sponza's CameraMain), else the framing ("front").
    let base = named.first().expect("a view").view;
    let centre_hit = tracer
        .closest_hit(base.position, base.forward, 0.0, f32::INFINITY)
        .expect("the view's centre hits the scene")
        .t;
    let target = base.position + base.forward * centre_hit;
    let right = base.forward.cross(base.up).normalize();
    let path: Vec<PinholeView> = (0..args.views)
        .map(|k| {
            let s = k as f32 / (args.views.max(2) - 1) as f32 - 0.5;
            let position = base.position + right * (0.3 * centre_hit * s);
            let forward = (target - position).normalize();
            let up = (base.up - forward * base.up.dot(forward)).normalize();
            PinholeView {
                position,
                forward,
                up,
                ..base
            }
        })
        .collect();
    let w = args.image;

    // Lattices of every triangle some view sees.
    let tris = scene.triangles();
    let spacing = args.spacing * centre_hit;
    let hits: Vec<Vec<Option<prt_trace::Hit>>> = path
        .iter()
        .map(|v| {
            (0..w * w)
                .into_par_iter()
                .map(|p| {
                    tracer.closest_hit(v.position, v.ray(p % w, p / w, w, w), 0.0, f32::INFINITY)
                })
                .collect()
        })
        .collect();
    let mut lattices: Vec<Option<Lattice>> = vec![None; tris.len()];
    let mut points: Vec<(Vec3, Vec3)> = Vec::new();
    for hit in hits.iter().flatten().flatten() {
        let t = hit.triangle as usize;
        if lattices[t].is_some() {
            continue;
        }
        let [a, b, c] = tris[t];
        let edge = (b - a).length().max((c - a).length()).max((c - b).length());
        let level = ((edge / spacing).ceil() as usize).clamp(1, 64);
        let centroid = (a + b + c) / 3.0;
        let mut normal = hit.normal;
        if normal.dot(path[0].position - centroid) < 0.0 {
            normal = -normal;
        }
        lattices[t] = Some(Lattice {
            level,
            first: points.len(),
            normal,
        });
        for j in 0..=level {
            for i in 0..=level - j {
                let p =
                    a + (b - a) * (i as f32 / level as f32) + (c - a) * (j as f32 / level as f32);
                points.push((p, normal));
            }
        }
    }
    let p_count = points.len();
    let texels = 6 * args.size * args.size;
    println!(
        "{} ({} triangles): {} triangles seen by {} views of {w}², {p_count} points, {:.1} M shadow rays, \
         transport {:.0} MB dense",
        args.scene,
        tris.len(),
        lattices.iter().flatten().count(),
        args.views,
        p_count as f64 * texels as f64 / 1e6,
        p_count as f64 * texels as f64 * 4.0 / 1e6
    );
    assert!(p_count <= args.max_points, "more than --max-points points");

    let shade_of = |hit: &prt_trace::Hit, eye: Vec3| -> Option<PixelShade> {
        let lattice = lattices[hit.triangle as usize]?;
        let l = lattice.level;
        let (a, b) = (hit.barycentrics.x * l as f32, hit.barycentrics.y * l as f32);
        let (i0, j0) = (a.floor().max(0.0) as usize, b.floor().max(0.0) as usize);
        let (fa, fb) = (a - i0 as f32, b - j0 as f32);
        let idx = |i: usize, j: usize| {
            let (i, j) = (i.min(l), j.min(l));
            let i = i.min(l - j);
            (lattice.first + lattice_index(l, i, j)) as u32
        };
        let pts = if fa + fb <= 1.0 {
            [
                (idx(i0, j0), 1.0 - fa - fb),
                (idx(i0 + 1, j0), fa),
                (idx(i0, j0 + 1), fb),
            ]
        } else {
            [
                (idx(i0 + 1, j0 + 1), fa + fb - 1.0),
                (idx(i0, j0 + 1), 1.0 - fa),
                (idx(i0 + 1, j0), 1.0 - fb),
            ]
        };
        let [v0, v1, v2] = tris[hit.triangle as usize];
        let position = v0 * (1.0 - hit.barycentrics.x - hit.barycentrics.y)
            + v1 * hit.barycentrics.x
            + v2 * hit.barycentrics.y;
        let frame = local_frame(lattice.normal);
        Some(PixelShade {
            points: pts,
            wo: frame * (eye - position).normalize(),
            frame,
        })
    };
    let pixels: Vec<Vec<Option<PixelShade>>> = hits
        .iter()
        .zip(&path)
        .map(|(h, v)| {
            h.iter()
                .map(|hit| hit.as_ref().and_then(|hit| shade_of(hit, v.position)))
                .collect()
        })
        .collect();

    // The BRDF factorisation.
    let brdf = blinn(args.exponent);
    let clock = Instant::now();
    let factorisation = BrdfFactorisation::fit(
        &brdf,
        &FactorisationConfig {
            grid: args.brdf_grid,
            terms: args.brdf_terms,
        },
    )
    .expect("factorisation");
    let mut table = Table::new(&["K", "relative L2 error of the tabulated BRDF"]);
    for k in [1, 2, 3, 4, 6, 8, 10, 16] {
        table.row(vec![
            k.to_string(),
            format!("{:.4}", factorisation.truncation_error(k)),
        ]);
    }
    println!(
        "\n## BRDF factorisation (Blinn-Phong exponent {}, {}² grid, {:.1} s)\n\n{}",
        args.exponent,
        args.brdf_grid,
        clock.elapsed().as_secs_f64(),
        table.markdown()
    );
    let k_terms = args.brdf_terms;

    // Trace: per point V cos Ω per texel and the K glossy rows.
    let rays = CubeRays::new(args.size, 1).expect("cube rays");
    let directions: Vec<Vec3> = (0..texels)
        .map(|t| {
            let n = args.size;
            let (face, y, x) = (t / (n * n), (t / n) % n, t % n);
            let centre = |i: usize| (2.0 * i as f64 + 1.0) / n as f64 - 1.0;
            cube_to_direction(face, centre(x), centre(y))
        })
        .collect();
    let clock = Instant::now();
    let traced: Vec<(Vec<f32>, Vec<SparseRow>)> = points
        .par_iter()
        .map_init(
            || CubemapHaar::new(args.size).expect("size"),
            |haar, &(p, n)| {
                let frame = local_frame(n);
                let mut vis_cos = vec![0.0f32; texels];
                let mut rows = vec![0.0f32; k_terms * texels];
                let mut g = vec![0.0f32; k_terms];
                rays.trace(&tracer, p, n, offset, |t, dir, omega| {
                    let weight = n.dot(dir) * omega;
                    vis_cos[t] += weight;
                    factorisation.in_factors(frame * dir, &mut g);
                    for k in 0..k_terms {
                        rows[k * texels + t] += g[k] * weight;
                    }
                });
                let sparse = rows
                    .chunks_exact_mut(texels)
                    .map(|row| {
                        haar.forward(row).expect("row");
                        let mut order: Vec<u32> = (0..texels as u32)
                            .filter(|&j| row[j as usize] != 0.0)
                            .collect();
                        order.sort_by(|a, b| {
                            row[*b as usize]
                                .abs()
                                .total_cmp(&row[*a as usize].abs())
                                .then(a.cmp(b))
                        });
                        order.truncate(args.keep);
                        order.sort_unstable();
                        order.iter().map(|&j| (j, row[j as usize])).collect()
                    })
                    .collect();
                (vis_cos, sparse)
            },
        )
        .collect();
    println!(
        "traced {p_count} points × {texels} texels in {:.1} s",
        clock.elapsed().as_secs_f64()
    );
    let (vis_cos, glossy): (Vec<Vec<f32>>, Vec<Vec<SparseRow>>) = traced.into_iter().unzip();
    let oracle = SparseRows {
        cols: texels,
        rows: glossy.into_iter().flatten().collect(),
    };
    let transport =
        SparseTransport::from_oracle(&oracle, args.keep, &NoProgress).expect("transport");
    drop(oracle);
    println!(
        "glossy transport: {} rows, {} entries ({:.1} MB)",
        transport.rows(),
        transport.nnz(),
        transport.nnz() as f64 * 4.0 / 1e6
    );

    // Lighting.
    let layout = CubemapLayout::new(args.size).expect("layout");
    let bands = layout.band_count();
    let rotation =
        Rotation::new(map, args.size, args.speed.to_radians(), args.stop).expect("rotation");
    let mut haar = CubemapHaar::new(args.size).expect("size");
    let frames: Vec<(Vec<f32>, Vec<f32>)> = (0..args.frames)
        .into_par_iter()
        .map(|f| {
            let texel = rotation.frame(f).expect("frame").into_data();
            let mut coeffs = texel.clone();
            CubemapHaar::new(args.size)
                .expect("size")
                .forward(&mut coeffs)
                .expect("haar");
            (texel, coeffs)
        })
        .collect();

    let render = |coeffs: &[f32], view: usize| -> Vec<f32> {
        pixels[view]
            .iter()
            .flat_map(|px| {
                let mut out = [0.0f32; 3];
                if let Some(px) = px {
                    let mut lit = vec![0.0f32; k_terms * 3];
                    for &(v, b) in &px.points {
                        for (l, c) in lit.iter_mut().zip(&coeffs[v as usize * k_terms * 3..]) {
                            *l += b * c;
                        }
                    }
                    factorisation.shade(px.wo, &lit, &mut out);
                }
                out
            })
            .collect()
    };
    let plane = texels;
    let reference = |texel: &[f32], view: usize| -> Vec<f32> {
        pixels[view]
            .par_iter()
            .flat_map_iter(|px| {
                let mut out = [0.0f64; 3];
                if let Some(px) = px {
                    for t in 0..texels {
                        let v: f32 = px
                            .points
                            .iter()
                            .map(|&(p, b)| b * vis_cos[p as usize][t])
                            .sum();
                        if v == 0.0 {
                            continue;
                        }
                        let rho = brdf(px.frame * directions[t], px.wo) * v;
                        for (c, o) in out.iter_mut().enumerate() {
                            *o += (rho * texel[c * plane + t]) as f64;
                        }
                    }
                }
                out.map(|x| x as f32)
            })
            .collect()
    };

    // §7.2, lighting moving, view fixed.
    let approx_for = |policy: Policy, terms: usize| {
        Approximator::for_cubemap(&layout, 3, Weighting::Area, terms, policy).expect("approximator")
    };
    let mut methods: Vec<(String, Approximator, Relighter)> = [
        (
            "NWA-30".to_string(),
            approx_for(Policy::NonIncremental, args.terms),
        ),
        (
            "NWA-60".to_string(),
            approx_for(Policy::NonIncremental, 2 * args.terms),
        ),
        (
            "PBI-30".to_string(),
            approx_for(Policy::PerBand(BandStrategy::Exhaustive), args.terms),
        ),
        (
            "exact".to_string(),
            approx_for(Policy::NonIncremental, layout.len()),
        ),
    ]
    .into_iter()
    .map(|(n, a)| {
        (
            n,
            a,
            Relighter::new(transport.clone(), 3, bands).expect("relighter"),
        )
    })
    .collect();
    let mut table = Table::new(&[
        "frame",
        "angle°",
        "method",
        "error vs un-factorised",
        "error vs K-term exact",
        "terms",
        "ms",
    ]);
    for (f, (texel, coeffs)) in frames.iter().enumerate() {
        let truth = reference(texel, 0);
        let mut images = Vec::new();
        let mut spent = Vec::new();
        for (_, approx, engine) in &mut methods {
            let clock = Instant::now();
            let update = approx.step(coeffs).expect("step");
            spent.push((update.terms.len(), 0.0));
            engine.apply(update).expect("apply");
            let image = render(&engine.image(), 0);
            spent.last_mut().expect("pushed").1 = clock.elapsed().as_secs_f64() * 1e3;
            images.push(image);
        }
        let exact = images.last().expect("exact").clone();
        if f % 4 == 0 || f + 1 == args.frames || (f >= args.stop && f < args.stop + 4) {
            for ((name, _, _), (image, (terms, ms))) in
                methods.iter().zip(images.iter().zip(&spent))
            {
                table.row(vec![
                    f.to_string(),
                    format!("{:.0}", rotation.angle(f).to_degrees()),
                    name.clone(),
                    format!("{:.4}", relative_rms(image, &truth)),
                    format!("{:.4}", relative_rms(image, &exact)),
                    terms.to_string(),
                    format!("{ms:.1}"),
                ]);
            }
        }
    }
    println!(
        "\n## §7.2 glossy relighting while the lighting rotates ({}°/frame, stops at frame {}; view 0)\n\n{}",
        args.speed,
        args.stop,
        table.markdown()
    );

    // §7.2, lighting fixed (converged), camera moving.
    let last = &frames.last().expect("frames").1;
    let pbi = &mut methods[2];
    let mut settle = 0;
    while pbi.1.approximation() != &last[..] && settle < 1000 {
        let update = pbi.1.step(last).expect("step");
        pbi.2.apply(update).expect("apply");
        settle += 1;
    }
    let mut direct_approx = approx_for(Policy::NonIncremental, layout.len());
    let mut direct = Relighter::new(transport.clone(), 3, bands).expect("relighter");
    direct
        .apply(direct_approx.step(last).expect("step"))
        .expect("apply");
    let (inc_terms, direct_terms) = (pbi.2.image(), direct.image());
    let last_texel = &frames.last().expect("frames").0;
    let mut table = Table::new(&[
        "view",
        "PBI terms spent",
        "max |incremental − direct| / max |direct|",
        "bit-identical pixels",
        "error vs un-factorised",
    ]);
    for view in 0..path.len() {
        let update = pbi.1.step(last).expect("step");
        let spent = update.terms.len();
        pbi.2.apply(update).expect("apply");
        let (a, b) = (render(&pbi.2.image(), view), render(&direct_terms, view));
        let scale = b.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let diff = a
            .iter()
            .zip(&b)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        let same = a.iter().zip(&b).filter(|(x, y)| x == y).count();
        table.row(vec![
            view.to_string(),
            spent.to_string(),
            format!("{:.2e}", diff / scale.max(1e-30)),
            format!("{same} / {}", a.len()),
            format!("{:.4}", relative_rms(&a, &reference(last_texel, view))),
        ]);
    }
    let term_diff = inc_terms
        .iter()
        .zip(&direct_terms)
        .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
    println!(
        "\n## §7.2 camera path under fixed lighting (PBI converged after {settle} more frames; \
         lit terms max |Δ| {term_diff:.2e})\n\n{}",
        table.markdown()
    );

    // §7.3: incremental CPCA on the diffuse rows.
    let clock = Instant::now();
    let mut rows = Array2::<f32>::zeros((p_count, texels));
    for (mut row, v) in rows.rows_mut().into_iter().zip(&vis_cos) {
        let r = row.as_slice_mut().expect("contiguous");
        for (x, y) in r.iter_mut().zip(v) {
            *x = y * std::f32::consts::FRAC_1_PI;
        }
        haar.forward(r).expect("row");
    }
    let field = GridField::from_data(
        [p_count, 1, 1],
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        },
        rows.clone(),
    )
    .expect("field");
    let fit = prt_core::Compressor::compress(
        &ClusteredPca::new(args.basis, args.clusters),
        &field,
        &NoProgress,
    )
    .expect("CPCA");
    let model = CpcaModel::new(
        fit.labels().to_vec(),
        fit.bases().as_slice().expect("contiguous"),
        fit.coefficients()
            .as_standard_layout()
            .as_slice()
            .expect("contiguous")
            .to_vec(),
        args.clusters,
        args.basis,
        texels,
    )
    .expect("model");
    let nnz: usize = rows.iter().filter(|&&v| v != 0.0).count();
    println!(
        "\n## §7.3 CPCA of {p_count} diffuse rows ({} non-zeros), C = {}, S = {}: fitted in {:.1} s",
        nnz,
        args.clusters,
        args.basis,
        clock.elapsed().as_secs_f64()
    );
    let quarter = (args.basis / 4).max(1);
    let mut cpca: Vec<(String, Approximator, CpcaRelighter, PointUpdate)> = vec![
        (
            format!("inc CPCA: PBI-{}, BI S/4 = {quarter}", args.terms),
            approx_for(Policy::PerBand(BandStrategy::Exhaustive), args.terms),
            CpcaRelighter::new(model.clone(), 3, bands).expect("engine"),
            PointUpdate::Incremental(quarter),
        ),
        (
            format!("CPCA S = {}: NWA-{}", args.basis, args.terms),
            approx_for(Policy::NonIncremental, args.terms),
            CpcaRelighter::new(model.clone(), 3, bands).expect("engine"),
            PointUpdate::All,
        ),
        (
            format!("CPCA S = {quarter}: NWA-{}", args.terms),
            approx_for(Policy::NonIncremental, args.terms),
            CpcaRelighter::new(model.truncated(quarter).expect("truncate"), 3, bands)
                .expect("engine"),
            PointUpdate::All,
        ),
        (
            format!("CPCA S = {}: PBI-{}", args.basis, args.terms),
            approx_for(Policy::PerBand(BandStrategy::Exhaustive), args.terms),
            CpcaRelighter::new(model.clone(), 3, bands).expect("engine"),
            PointUpdate::All,
        ),
        (
            format!("CPCA S = {}: exact lighting", args.basis),
            approx_for(Policy::NonIncremental, layout.len()),
            CpcaRelighter::new(model.clone(), 3, bands).expect("engine"),
            PointUpdate::All,
        ),
    ];
    let mut table = Table::new(&[
        "frame",
        "method",
        "error vs uncompressed exact",
        "multiply-adds",
        "ms",
    ]);
    let extra = 8;
    for f in 0..args.frames + extra {
        let (_, coeffs) = &frames[f.min(args.frames - 1)];
        let mut truth = vec![0.0f32; p_count * 3];
        truth.par_chunks_mut(3).enumerate().for_each(|(v, out)| {
            let row = rows.row(v);
            for (c, o) in out.iter_mut().enumerate() {
                *o = row
                    .iter()
                    .zip(&coeffs[c * plane..])
                    .map(|(r, l)| r * l)
                    .sum();
            }
        });
        for (name, approx, engine, points) in &mut cpca {
            let clock = Instant::now();
            let update = approx.step(coeffs).expect("step");
            let work = engine.apply(update, *points).expect("apply");
            let ms = clock.elapsed().as_secs_f64() * 1e3;
            if f % 4 == 0 || (f >= args.stop && f < args.stop + 4) || f + 1 == args.frames + extra {
                table.row(vec![
                    f.to_string(),
                    name.clone(),
                    format!("{:.4}", relative_rms(engine.image(), &truth)),
                    work.total().to_string(),
                    format!("{ms:.2}"),
                ]);
            }
        }
    }
    println!(
        "\nuncompressed exact product: {} multiply-adds per frame (non-zeros × 3)\n\n{}",
        nnz * 3,
        table.markdown()
    );
}
