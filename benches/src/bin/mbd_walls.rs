//! MBD with basis kernels that do not cross walls (`prt_mbd::wall_aware_basis`) against MBD on
//! the plain hat grid, BPCA and CPCA on a traced volume, at rank `MBD_L` (8) with `MBD_B`³ (5³)
//! basis nodes / blocks / clusters, MBD with the default solver (≤ `MBD_ITERS` = 128
//! iterations).
//!
//! `MBD_FIELD=sponza|cornell MBD_N=48 nice -n 10 cargo run --release -p prt-benches --bin mbd_walls`
//!
//! The volumes are read from `target/mbd_cache/{scene}_{n}_r256_c64_s0.f32`, which
//! `mbd_sweep` writes when it traces them (`MBD_FIELD=sponza MBD_N=48 mbd_sweep walls`); the
//! validity mask is the baker's (invalid voxels hold exactly zero transfer).
//!
//! Methods (`MBD_METHODS`, comma-separated, default `HAT,WALL,BPCA,CPCA`): `HAT` (MBD, hat
//! basis), `HAT-INTERP` (the wall-aware family with every voxel valid: the hat sampled at the
//! voxel centres and interpolated, the control for what the cuts themselves do), `WALL` (MBD,
//! wall-aware hat basis), `HAT-CENTRES` / `WALL-CENTRES` (the hat grid spanning the box of
//! the voxel centres instead of the field's box, plain / cut at walls; since `Mbd` and
//! `wall_aware_basis` span that box themselves (commit 9b8a77b and after), `HAT` and `WALL`
//! give the same models: docs/results.md's field-box rows were measured before), `WALL-TRANSFER` (that
//! cut also at the `MBD_BARRIER_SHARE` (0.2) of valid voxels whose transfer jumps most to a
//! neighbour: flood fills stop at shadow boundaries too), `WALL-D` (wall-aware with `max_detour` =
//! `MBD_DETOUR`, default 1.5), `WALL-LOS` (wall-aware, line of sight from the node's seeds), `SHEPARD-E` (MBD, energy-placed Shepard kernels of
//! `scene_adapted_basis`), `SHEPARD-E-WALL` (those kernels cut back at walls), `BPCA`, `CPCA`, and as controls
//! (with `CPCA`) `CLUSTER` / `CLUSTER-SMOOTH`: MBD whose basis kernels are CPCA's cluster
//! indicators, sharp or smoothed over the 3³ neighbours, interpolated between voxel centres
//! (global- and local-PCA starts; the time excludes CPCA's).
//!
//! `MBD_SEED` sets the solver's seed, `MBD_TOL` its stopping tolerance (0: every solve runs
//! exactly `MBD_ITERS` iterations, so that kernel families are compared at equal iterations).
//!
//! Reported per method: iterations, wall and process CPU time (kernel construction included),
//! relative MSE on jittered samples and its ratio to CPCA's, the relative error at valid voxel
//! centres, the error by Chebyshev distance to the nearest invalid voxel (share of the field's
//! energy) and its ratio to CPCA's per bin, the seam metric against the hat grid's basis cells
//! (the same labels for every MBD variant), and for the wall-aware kernels the number of valid
//! voxels that fell back to the base weights and the mean / largest kernel count.

use std::time::Instant;

use prt_benches::Table;
use prt_benches::mbd::{
    CAP, basis_nodes, cached_volume_or_exit, distance_name, env_or, load_average, measure,
    method_enabled, voxel_energy, wall_bins_of_grid, wall_distance,
};
use prt_core::{Compressor, FieldModel, GridField, NoProgress, SpatialKernels, resample_to_grid};
use prt_mbd::*;

fn enabled(method: &str) -> bool {
    method_enabled(method, "HAT,WALL,BPCA,CPCA")
}

/// The share of the base kernels' weight at valid voxel centres that the wall-aware family
/// drops (nodes that do not reach the voxel), plain and weighted by the voxel's energy.
fn cut_share<K: SpatialKernels>(basis: &WallAware<K>, f: &GridField, valid: &[bool]) -> (f64, f64) {
    let mut w = prt_core::KernelWeights::default();
    let (mut plain, mut weighted, mut count, mut energy) = (0.0, 0.0, 0.0, 0.0);
    for v in (0..f.num_voxels()).filter(|&v| valid[v]) {
        basis
            .base()
            .eval(f.centre_of(v), &mut w)
            .expect("base covers the voxel centres");
        let kept: Vec<u32> = basis.voxel_weights(v).map(|(i, _)| i).collect();
        let dropped: f64 = w
            .iter()
            .filter(|(i, _)| !kept.contains(i))
            .map(|(_, x)| f64::from(x))
            .sum::<f64>()
            / w.sum();
        let e: f64 = f.voxel(v).iter().map(|&x| f64::from(x).powi(2)).sum();
        plain += dropped;
        weighted += e * dropped;
        count += 1.0;
        energy += e;
    }
    (plain / count, weighted / energy)
}

/// What a wall-aware family cut and costs, for the table: the share of the base weight it cut
/// ([`cut_share`]), its fallback voxels, kernels per voxel centre and at a point, build time.
fn describe<K: SpatialKernels>(
    basis: &WallAware<K>,
    build: f64,
    f: &GridField,
    valid: &[bool],
) -> String {
    let (plain, weighted) = cut_share(basis, f, valid);
    format!(
        "cuts {:.0} % of the base weight at valid voxel centres ({:.0} % energy-weighted); {} fallback voxels, {:.2} kernels per voxel centre, ≤ {} at a point, built in {build:.2} s",
        100.0 * plain,
        100.0 * weighted,
        basis.fallbacks(),
        basis.mean_voxel_support(),
        basis.max_support(),
    )
}

/// The validity mask with the `share` of valid voxels where the field changes most from voxel
/// to voxel also marked as barriers: largest relative jump `‖f(v) − f(u)‖ / (‖f(v)‖ + ‖f(u)‖)`
/// to a valid face neighbour `u`. Flood fills then stop at shadow and occlusion boundaries as
/// well as at geometry.
fn with_transfer_barriers(f: &GridField, valid: &[bool], share: f64) -> Vec<bool> {
    let dims = f.dims();
    let norm = |v: usize| {
        f.voxel(v)
            .iter()
            .map(|&x| f64::from(x).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let jump = |v: usize| -> f64 {
        let c = f.coords(v);
        let stride = [1, dims[0], dims[0] * dims[1]];
        let mut largest = 0.0f64;
        for k in 0..3 {
            let neighbours = [
                (c[k] > 0).then(|| v - stride[k]),
                (c[k] + 1 < dims[k]).then(|| v + stride[k]),
            ];
            for u in neighbours.into_iter().flatten().filter(|&u| valid[u]) {
                let d: f64 = f
                    .voxel(v)
                    .iter()
                    .zip(f.voxel(u))
                    .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                    .sum::<f64>()
                    .sqrt();
                largest = largest.max(d / (norm(v) + norm(u)).max(f64::MIN_POSITIVE));
            }
        }
        largest
    };
    let mut jumps: Vec<(f64, usize)> = (0..f.num_voxels())
        .filter(|&v| valid[v])
        .map(|v| (jump(v), v))
        .collect();
    jumps.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut mask = valid.to_vec();
    // Keep at least one valid voxel.
    let barriers = ((share * jumps.len() as f64) as usize).min(jumps.len().saturating_sub(1));
    for &(_, v) in &jumps[..barriers] {
        mask[v] = false;
    }
    mask
}

struct Row {
    name: String,
    iterations: String,
    wall: f64,
    cpu: f64,
    relative_mse: f64,
    /// Squared error at voxel centres per wall-distance bin.
    bins: [f64; CAP + 1],
    seam_excess: f64,
    seam_ratio: f64,
}

fn main() {
    let scene = std::env::var("MBD_FIELD").unwrap_or_else(|_| "sponza".into());
    let n: usize = env_or("MBD_N", 48);
    let (l, b) = (env_or("MBD_L", 8usize), env_or("MBD_B", 5usize));
    let iterations: usize = env_or("MBD_ITERS", 128);
    let detour: f32 = env_or("MBD_DETOUR", 1.5);
    let field = cached_volume_or_exit("mbd_walls", &scene, n);
    let f = &field;
    let valid = nonzero_voxels(f);
    let invalid = valid.iter().filter(|v| !**v).count();
    let dims = f.dims();
    let nodes = basis_nodes(f, b);
    let count: usize = nodes.iter().product();
    println!(
        "traced {scene} {}×{}×{} × {}, {invalid} invalid voxels; L = {l}, {count} basis nodes; load average before: {}",
        dims[0],
        dims[1],
        dims[2],
        f.dim(),
        load_average()
    );
    let distance = wall_distance(f, &valid);
    let total = voxel_energy(f, &|_| true);
    let valid_energy = voxel_energy(f, &|v| valid[v]);
    let options = MbdOptions {
        rank: l,
        max_iterations: iterations,
        seed: env_or("MBD_SEED", MbdOptions::default().seed),
        // 0: no early stop, every solve runs exactly `MBD_ITERS` iterations.
        tolerance: env_or("MBD_TOL", MbdOptions::default().tolerance),
        ..MbdOptions::default()
    };
    let mbd = Mbd {
        basis_nodes: nodes,
        options: options.clone(),
    };
    let (coefficient_kernels, hat) = mbd.kernels(f).expect("kernels");
    let hat_labels = kernel_labels(&hat, f).expect("labels");
    let mut rows: Vec<Row> = Vec::new();
    let mut add = |name: String,
                   iterations: String,
                   wall: f64,
                   cpu: f64,
                   model: &dyn FieldModel| {
        let eval = EvalOptions::default();
        let e = evaluate(model, f, &eval).expect("evaluate");
        let recon = resample_to_grid(model, f.dims(), f.bounds()).expect("resample");
        let bins = wall_bins_of_grid(f, &recon, &distance);
        let seam = seam_metric_with(
            f,
            &recon,
            &hat_labels,
            &SeamOptions {
                denoise_sigma: 1.0,
                valid: Some(&valid),
            },
        )
        .expect("seam");
        eprintln!(
            "{name}: {iterations} iterations, {wall:.1} s (CPU {cpu:.1} s), relative MSE {:.3e}",
            e.relative_mse
        );
        rows.push(Row {
            name,
            iterations,
            wall,
            cpu,
            relative_mse: e.relative_mse,
            bins,
            seam_excess: seam.excess(),
            seam_ratio: seam.ratio(),
        });
    };
    if enabled("HAT") {
        let ((model, report), wall, cpu) = measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        add(
            format!("MBD, {count} hat kernels"),
            report.history.len().to_string(),
            wall,
            cpu,
            &model,
        );
    }
    // The hat grid over the box of the voxel centres (constant in the outer half voxel, like
    // the field's own trilinear sampling and the coefficient kernels).
    let centre_hat = prt_kernels::HatGrid::new(nodes, voxel_centre_box(f)).expect("hat");
    if enabled("HAT-CENTRES") {
        let ((model, report), wall, cpu) = measure(|| {
            solve(
                f,
                coefficient_kernels.clone(),
                centre_hat.clone(),
                &options,
                &NoProgress,
            )
            .expect("mbd")
        });
        add(
            format!("MBD, {count} hat kernels over the voxel centres' box"),
            report.history.len().to_string(),
            wall,
            cpu,
            &model,
        );
    }
    let all_valid = vec![true; f.num_voxels()];
    let wall_variants = [
        ("HAT-INTERP", f32::INFINITY, false),
        ("WALL", f32::INFINITY, false),
        ("WALL-D", detour, false),
        ("WALL-LOS", f32::INFINITY, true),
        ("WALL-CENTRES", f32::INFINITY, false),
        ("WALL-TRANSFER", f32::INFINITY, false),
    ];
    let barrier_share: f64 = env_or("MBD_BARRIER_SHARE", 0.2);
    let transfer_mask = if enabled("WALL-TRANSFER") {
        with_transfer_barriers(f, &valid, barrier_share)
    } else {
        Vec::new()
    };
    for (key, max_detour, line_of_sight) in wall_variants {
        if !enabled(key) {
            continue;
        }
        let wall_options = WallOptions {
            max_detour,
            line_of_sight,
        };
        let ((basis, build), ..) = measure(|| {
            let t = Instant::now();
            // The control: the same family with every voxel valid (nothing cut).
            let mask = match key {
                "HAT-INTERP" => &all_valid,
                "WALL-TRANSFER" => &transfer_mask,
                _ => &valid,
            };
            let basis = if key == "WALL-CENTRES" || key == "WALL-TRANSFER" {
                WallAware::from_hat(centre_hat.clone(), dims, f.bounds(), mask, &wall_options)
            } else {
                wall_aware_basis(f, mask, nodes, &wall_options)
            }
            .expect("wall basis");
            (basis, t.elapsed().as_secs_f64())
        });
        let text = describe(&basis, build, f, &valid);
        let ((model, report), wall, cpu) = measure(|| {
            solve(f, coefficient_kernels.clone(), basis, &options, &NoProgress).expect("mbd")
        });
        let detour_text = match (max_detour.is_finite(), line_of_sight) {
            (true, _) => format!(", detour ≤ {max_detour}"),
            (false, true) => ", line of sight".into(),
            (false, false) => String::new(),
        };
        let family = match key {
            "HAT-INTERP" => {
                "hat kernels sampled at voxel centres and interpolated (wall-aware with every voxel valid: the control)".to_string()
            }
            "WALL-CENTRES" => "wall-aware hat kernels over the voxel centres' box".into(),
            "WALL-TRANSFER" => format!(
                "hat kernels over the voxel centres' box cut at walls and at the {:.0} % of valid voxels with the largest transfer jumps",
                100.0 * barrier_share
            ),
            _ => "wall-aware hat kernels".into(),
        };
        add(
            format!("MBD, {count} {family}{detour_text} ({text})"),
            report.history.len().to_string(),
            wall + build,
            cpu + build,
            &model,
        );
    }
    for (key, cut) in [("SHEPARD-E", false), ("SHEPARD-E-WALL", true)] {
        if !enabled(key) {
            continue;
        }
        let ((model_report, text), wall, cpu) = measure(|| {
            let shepard = scene_adapted_basis(f, &valid, count, &AdaptedBasisOptions::default())
                .expect("adapted basis");
            if cut {
                let t = Instant::now();
                let basis =
                    WallAware::new(shepard, dims, f.bounds(), &valid, &WallOptions::default())
                        .expect("wall basis");
                let build = t.elapsed().as_secs_f64();
                let text = describe(&basis, build, f, &valid);
                let (model, report) =
                    solve(f, coefficient_kernels.clone(), basis, &options, &NoProgress)
                        .expect("mbd");
                (
                    (Box::new(model) as Box<dyn FieldModel>, report),
                    format!(" cut at walls ({text})"),
                )
            } else {
                let (model, report) = solve(
                    f,
                    coefficient_kernels.clone(),
                    shepard,
                    &options,
                    &NoProgress,
                )
                .expect("mbd");
                (
                    (Box::new(model) as Box<dyn FieldModel>, report),
                    String::new(),
                )
            }
        });
        let (model, report) = model_report;
        add(
            format!("MBD, {count} energy-placed Shepard kernels{text}"),
            report.history.len().to_string(),
            wall,
            cpu,
            model.as_ref(),
        );
    }
    if enabled("BPCA") {
        let (m, wall, cpu) = measure(|| {
            BlockPca {
                rank: l,
                blocks: nodes,
                window: 1.0,
            }
            .compress(f, &NoProgress)
            .expect("bpca")
        });
        add("BPCA".into(), "–".into(), wall, cpu, &m);
    }
    if enabled("CPCA") {
        let (m, wall, cpu) = measure(|| {
            ClusteredPca::new(l, count)
                .compress(f, &NoProgress)
                .expect("cpca")
        });
        add("CPCA".into(), "–".into(), wall, cpu, &m);
        for (key, smooth) in [("CLUSTER", false), ("CLUSTER-SMOOTH", true)] {
            if !enabled(key) {
                continue;
            }
            for init in [Init::GlobalPca, Init::LocalPca] {
                let ((model, report), wall, cpu) = measure(|| {
                    let len = m
                        .labels()
                        .iter()
                        .map(|&k| k as usize + 1)
                        .max()
                        .unwrap_or(1);
                    let smoothing = LabelSmoothing {
                        radius: usize::from(smooth),
                        falloff: 0.5,
                    };
                    let basis = LabelKernels::new(
                        f.dims(),
                        f.bounds(),
                        m.labels(),
                        len,
                        Some(&valid),
                        &smoothing,
                    )
                    .expect("cluster kernels");
                    let options = MbdOptions {
                        init,
                        ..options.clone()
                    };
                    solve(f, coefficient_kernels.clone(), basis, &options, &NoProgress)
                        .expect("mbd")
                });
                let shape = if smooth {
                    "smoothed over 3³ valid neighbours"
                } else {
                    "indicators"
                };
                add(
                    format!(
                        "MBD, {} kernels from CPCA's clusters ({shape}, ≤ {} at a point), {init:?} start (control)",
                        model.basis_kernels().len(),
                        model.basis_kernels().max_support()
                    ),
                    report.history.len().to_string(),
                    wall,
                    cpu,
                    &model,
                );
            }
        }
    }
    let cpca = rows.iter().find(|r| r.name == "CPCA");
    let mut header = vec![
        "method".to_string(),
        "iterations".into(),
        "time (CPU)".into(),
        "relative MSE (jittered)".into(),
        "/ CPCA".into(),
        "valid only (centres)".into(),
    ];
    header.extend((1..=CAP).map(|d| {
        let share = voxel_energy(f, &|v| distance[v] == d) / total;
        format!(
            "distance {} ({:.0} %): / CPCA",
            distance_name(d),
            100.0 * share + 0.0
        )
    }));
    header.extend(["seam excess".into(), "seam ratio".into()]);
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut table = Table::new(&header);
    for r in &rows {
        let mut cells = vec![
            r.name.clone(),
            r.iterations.clone(),
            format!("{:.1} s ({:.1} s)", r.wall, r.cpu),
            format!("{:.3e}", r.relative_mse),
            cpca.map_or("–".into(), |c| {
                format!("{:.2}", r.relative_mse / c.relative_mse)
            }),
            format!("{:.3e}", r.bins[1..].iter().sum::<f64>() / valid_energy),
        ];
        cells.extend((1..=CAP).map(|d| match cpca {
            Some(c) if c.bins[d] > 0.0 => {
                format!("{:.2e} ({:.2})", r.bins[d] / total, r.bins[d] / c.bins[d])
            }
            _ => format!("{:.2e}", r.bins[d] / total),
        }));
        cells.extend([
            format!("{:.2e}", r.seam_excess),
            format!("{:.2}", r.seam_ratio),
        ]);
        table.row(cells);
    }
    println!("{}", table.markdown());
    println!("load average after: {}", load_average());
}
