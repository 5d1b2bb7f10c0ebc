//! MBD whose basis kernels are clustered PCA's clusters, smoothed (`prt_mbd::ClusteredMbd`),
//! against MBD on the hat grid, BPCA and CPCA, at rank `MBD_L` (8) with `MBD_B`³ (5³)
//! basis nodes / blocks / clusters; every MBD with the default solver (≤ `MBD_ITERS` = 128
//! iterations, `MBD_TOL` its stopping tolerance).
//!
//! `MBD_FIELD=synthetic|cornell|sponza MBD_N=48 nice -n 10 cargo run --release -p prt-benches --bin mbd_clustered`
//!
//! The synthetic field is `mbd_sweep`'s (`MBD_N`³ × 324, seed 1); the traced volumes are read
//! from `target/mbd_cache/{scene}_{n}_r256_c64_s0.f32`, which `mbd_sweep` writes when it traces
//! them (`MBD_FIELD=sponza MBD_N=48 mbd_sweep walls`).
//!
//! Methods (`MBD_METHODS`, comma-separated, default `HAT,BPCA,CPCA,CMBD`); `CPCA-MAJORITY` (a
//! control: CPCA's labels after 1..=`MBD_PASSES` (3) rounds of a majority filter over the
//! valid 3³ neighbours, each cluster's subspace refitted, every voxel projected: how much of
//! CPCA's lead comes from switching subspaces from voxel to voxel); `CMBD` runs once per
//! smoothing radius in `MBD_RADII` (default `0,1,2`) with falloff `MBD_FALLOFF` (0.5), the
//! basis started from the clusters' own subspaces aligned to the global one (`MBD_START=aligned`,
//! the default) or from the global subspace (`MBD_START=global`, `mbd_walls`' control);
//! `CMBD-RELABEL`: radius `MBD_RELABEL_RADIUS` (2), then `MBD_RELABEL_ROUNDS` (2) rounds of
//! relabelling every valid voxel to the kernel whose fitted basis captures most of its energy
//! and solving again from the fitted bases.
//! With `MBD_SWEEPS` > 0 (default 0) every MBD row is followed by the same model after that many
//! sweeps of the exact `polish` (tolerance `MBD_PTOL`, default 0: all sweeps; acceleration
//! `MBD_ACCEL`: `cg` (default), `extrapolation` or `none`), with the exact
//! relative MSE before and after in its name; its time is the polish's alone.
//! `WBPCA` (blocks of twice the size, off by default) is a method too, and so is `PCA` (global
//! PCA, off by default: one basis everywhere, so it has no seams, and its seam ratios are the
//! floor the field's own structure sets at each set of boundaries).
//! Reported per method: iterations, wall and process CPU time (the `CMBD` rows exclude CPCA's
//! clustering, which the `CPCA` row times), relative MSE on jittered samples and its ratio to
//! CPCA's, and the seam
//! metric (σ = 1 denoised, valid voxels) at CPCA's cluster boundaries and at the hat grid's
//! basis cells, and the basis-projection seam ratio (`prt_mbd::projection_seam_ratio`, prt-cli's
//! seam view: the σ = 1 denoised field projected onto each voxel's basis) at CPCA's clusters and
//! at BPCA's blocks.

use prt_benches::Table;
use prt_benches::mbd::{
    basis_nodes, cached_volume_or_exit, env_or, load_average, measure, method_enabled,
    synthetic_field,
};
use prt_core::{Compressor, FieldModel, GridField, NoProgress, SpatialKernels, resample_to_grid};
use prt_mbd::*;

fn enabled(method: &str) -> bool {
    method_enabled(method, "HAT,BPCA,CPCA,CMBD")
}

/// The share of valid voxels with a valid face neighbour of another label.
fn boundary_share(f: &GridField, valid: &[bool], labels: &[u32]) -> f64 {
    let dims = f.dims();
    let stride = [1, dims[0], dims[0] * dims[1]];
    let on_boundary = (0..f.num_voxels())
        .filter(|&v| valid[v])
        .filter(|&v| {
            let c = f.coords(v);
            (0..3).any(|k| {
                [
                    (c[k] > 0).then(|| v - stride[k]),
                    (c[k] + 1 < dims[k]).then(|| v + stride[k]),
                ]
                .into_iter()
                .flatten()
                .any(|u| valid[u] && labels[u] != labels[v])
            })
        })
        .count();
    on_boundary as f64 / valid.iter().filter(|v| **v).count().max(1) as f64
}

/// One round of a majority filter: each valid voxel takes the most frequent label among its
/// valid 3³ neighbours (itself included; ties keep its own label, then the lowest).
fn majority_filter(f: &GridField, valid: &[bool], labels: &[u32]) -> Vec<u32> {
    let dims = f.dims().map(|d| d as i64);
    (0..f.num_voxels())
        .map(|v| {
            if !valid[v] {
                return labels[v];
            }
            let c = f.coords(v).map(|x| x as i64);
            let mut counts: Vec<(u32, usize)> = Vec::new();
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if (0..3).any(|k| q[k] < 0 || q[k] >= dims[k]) {
                            continue;
                        }
                        let u = (q[0] + dims[0] * (q[1] + dims[1] * q[2])) as usize;
                        if !valid[u] {
                            continue;
                        }
                        match counts.iter_mut().find(|e| e.0 == labels[u]) {
                            Some(e) => e.1 += 1,
                            None => counts.push((labels[u], 1)),
                        }
                    }
                }
            }
            let own = counts.iter().find(|e| e.0 == labels[v]).map_or(0, |e| e.1);
            counts
                .iter()
                .filter(|e| e.1 > own)
                .max_by_key(|e| (e.1, std::cmp::Reverse(e.0)))
                .map_or(labels[v], |e| e.0)
        })
        .collect()
}

/// Each valid voxel's label: the kernel whose fitted basis (orthonormalised) captures the most
/// of the voxel's energy; other voxels keep theirs.
fn relabelled(
    f: &GridField,
    valid: &[bool],
    model: &MbdModel<prt_kernels::HatGrid, LabelKernels>,
) -> Vec<u32> {
    let bases: Vec<ndarray::Array2<f64>> = model
        .basis()
        .outer_iter()
        .map(|b| {
            prt_linalg::thin_svd(b.mapv(f64::from).view())
                .expect("svd")
                .vt
        })
        .collect();
    (0..f.num_voxels())
        .map(|v| {
            if !valid[v] {
                return model.basis_kernels().labels()[v];
            }
            let x = ndarray::Array1::from_iter(f.voxel(v).iter().map(|&t| f64::from(t)));
            let energy = |b: &ndarray::Array2<f64>| b.dot(&x).iter().map(|c| c * c).sum::<f64>();
            (0..bases.len())
                .max_by(|&a, &b| energy(&bases[a]).total_cmp(&energy(&bases[b])))
                .unwrap_or(0) as u32
        })
        .collect()
}

struct Row {
    name: String,
    iterations: String,
    wall: f64,
    cpu: f64,
    relative_mse: f64,
    seams: [SeamMetric; 2],
    /// Basis-projection seam ratio at CPCA's clusters and at BPCA's blocks.
    projection: [f64; 2],
}

/// `model` after `MBD_SWEEPS` exact polish sweeps (none when 0), with a name giving the sweeps
/// and the exact relative MSE before and after, and the polish's wall and CPU time.
fn polished<B: PolishBasis>(
    f: &GridField,
    model: MbdModel<prt_kernels::HatGrid, B>,
) -> Option<(MbdModel<prt_kernels::HatGrid, B>, String, f64, f64)> {
    let sweeps: usize = env_or("MBD_SWEEPS", 0);
    if sweeps == 0 {
        return None;
    }
    let options = PolishOptions {
        sweeps,
        tolerance: env_or("MBD_PTOL", 0.0),
        acceleration: prt_benches::mbd::polish_acceleration(),
        ..PolishOptions::default()
    };
    let ((model, report), wall, cpu) =
        measure(|| polish(f, model, &options, &NoProgress).expect("polish"));
    for r in &report.history {
        eprintln!(
            "  polish {:?}{}: exact {:.4e} at {:.1} s ({} CG iterations)",
            r.step,
            if r.accepted { "" } else { " (rejected)" },
            r.loss.relative_mse(),
            r.elapsed,
            r.cg_iterations
        );
    }
    let done = report
        .history
        .iter()
        .filter(|r| r.step == PolishStep::Coefficients)
        .count();
    let name = format!(
        "+ {done} polish sweeps (exact {:.3e} → {:.3e})",
        report.initial.relative_mse(),
        report.last().relative_mse()
    );
    Some((model, name, wall, cpu))
}

/// The per-voxel bases of a clustered model, for the projection seams.
fn clustered_basis(model: &ClusterModel) -> LocalBasis<'_> {
    LocalBasis::Clustered {
        labels: model.labels(),
        bases: model.bases(),
    }
}

/// The moving basis of an MBD model, for the projection seams.
fn moving<B: SpatialKernels>(model: &MbdModel<prt_kernels::HatGrid, B>) -> LocalBasis<'_> {
    LocalBasis::Moving {
        kernels: model.basis_kernels(),
        basis: model.basis(),
    }
}

fn main() {
    let scene = std::env::var("MBD_FIELD").unwrap_or_else(|_| "sponza".into());
    let n: usize = env_or("MBD_N", 48);
    let (l, b) = (env_or("MBD_L", 8usize), env_or("MBD_B", 5usize));
    let field = if scene == "synthetic" {
        synthetic_field(n)
    } else {
        cached_volume_or_exit("mbd_clustered", &scene, n)
    };
    let f = &field;
    let valid = nonzero_voxels(f);
    let dims = f.dims();
    let nodes = basis_nodes(f, b);
    let count: usize = nodes.iter().product();
    println!(
        "{scene} {}×{}×{} × {}, {} invalid voxels; L = {l}, {count} basis nodes / clusters; load average before: {}",
        dims[0],
        dims[1],
        dims[2],
        f.dim(),
        valid.iter().filter(|v| !**v).count(),
        load_average()
    );
    let options = MbdOptions {
        rank: l,
        max_iterations: env_or("MBD_ITERS", 128),
        tolerance: env_or("MBD_TOL", MbdOptions::default().tolerance),
        ..MbdOptions::default()
    };
    let mbd = Mbd {
        basis_nodes: nodes,
        options: options.clone(),
    };
    let (_, hat) = mbd.kernels(f).expect("kernels");
    let hat_labels = kernel_labels(&hat, f).expect("labels");
    // Fitted once: the CPCA row and every clustered MBD (which starts from its clusters).
    let (cpca, cpca_wall, cpca_cpu) = measure(|| {
        ClusteredPca::new(l, count)
            .compress(f, &NoProgress)
            .expect("cpca")
    });
    let cluster_labels = cpca.labels().to_vec();
    println!(
        "CPCA's clusters: {:.1} % of the valid voxels have a valid face neighbour in another cluster",
        100.0 * boundary_share(f, &valid, &cluster_labels)
    );
    // BPCA is fitted up front: its blocks are the other boundaries of the projection seams.
    let (bpca, bpca_wall, bpca_cpu) = measure(|| {
        BlockPca {
            rank: l,
            blocks: nodes,
            window: 1.0,
        }
        .compress(f, &NoProgress)
        .expect("bpca")
    });
    let block_labels = bpca.labels().to_vec();
    let smoothed = blur_valid(f, &valid, 1.0).expect("blur");
    let mut rows: Vec<Row> = Vec::new();
    let mut add = |name: String,
                   iterations: String,
                   wall: f64,
                   cpu: f64,
                   model: &dyn FieldModel,
                   basis: LocalBasis<'_>| {
        let residuals = projection_residuals(&smoothed, &valid, &basis).expect("projection");
        let projection = [&cluster_labels, &block_labels].map(|labels| {
            residual_seam_ratio(&smoothed, &valid, labels, &residuals).expect("projection seams")
        });
        let e = evaluate(model, f, &EvalOptions::default()).expect("evaluate");
        let recon = resample_to_grid(model, f.dims(), f.bounds()).expect("resample");
        let seam = |labels: &[u32]| {
            seam_metric_with(
                f,
                &recon,
                labels,
                &SeamOptions {
                    denoise_sigma: 1.0,
                    valid: Some(&valid),
                },
            )
            .expect("seam")
        };
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
            seams: [seam(&cluster_labels), seam(&hat_labels)],
            projection,
        });
    };
    if enabled("CPCA") {
        // Its exact error: the trilinear energy of the difference of its voxel reconstruction.
        let mut difference = resample_to_grid(&cpca, f.dims(), f.bounds()).expect("resample");
        let mut values = difference.data_mut();
        values -= f.data();
        let exact = trilinear_energy(&difference) / trilinear_energy(f);
        add(
            format!("CPCA (exact {exact:.3e})"),
            "–".into(),
            cpca_wall,
            cpca_cpu,
            &cpca,
            clustered_basis(&cpca),
        );
    }
    if enabled("CPCA-MAJORITY") {
        let passes: usize = env_or("MBD_PASSES", 3);
        let mut labels = cluster_labels.clone();
        for pass in 1..=passes {
            labels = majority_filter(f, &valid, &labels);
            let (model, wall, cpu) = measure(|| {
                ClusteredPca::with_labels(f, labels.clone(), l, &NoProgress).expect("cpca")
            });
            add(
                format!(
                    "control: CPCA's labels majority-filtered ×{pass} ({:.1} % on a boundary), bases refitted",
                    100.0 * boundary_share(f, &valid, &labels)
                ),
                "–".into(),
                wall,
                cpu,
                &model,
                clustered_basis(&model),
            );
        }
    }
    if enabled("HAT") {
        let ((model, report), wall, cpu) = measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        add(
            format!("MBD, {count} hat kernels"),
            report.history.len().to_string(),
            wall,
            cpu,
            &model,
            moving(&model),
        );
        if let Some((polished, name, wall, cpu)) = polished(f, model) {
            add(
                format!("MBD, {count} hat kernels, {name}"),
                "–".into(),
                wall,
                cpu,
                &polished,
                moving(&polished),
            );
        }
    }
    if enabled("BPCA") {
        add(
            "BPCA".into(),
            "–".into(),
            bpca_wall,
            bpca_cpu,
            &bpca,
            clustered_basis(&bpca),
        );
    }
    if enabled("PCA") {
        let (m, wall, cpu) =
            measure(|| GlobalPca { rank: l }.compress(f, &NoProgress).expect("pca"));
        add(
            "control: global PCA (no seams)".into(),
            "–".into(),
            wall,
            cpu,
            &m,
            clustered_basis(&m),
        );
    }
    if enabled("WBPCA") {
        let (m, wall, cpu) = measure(|| {
            BlockPca {
                rank: l,
                blocks: nodes,
                window: 2.0,
            }
            .compress(f, &NoProgress)
            .expect("wbpca")
        });
        add(
            "WBPCA".into(),
            "–".into(),
            wall,
            cpu,
            &m,
            clustered_basis(&m),
        );
    }
    if enabled("CMBD") {
        let radii = std::env::var("MBD_RADII").unwrap_or_else(|_| "0,1,2".into());
        let falloff: f32 = env_or("MBD_FALLOFF", 0.5);
        let start = match std::env::var("MBD_START").as_deref() {
            Ok("global") => ClusterStart::GlobalPca,
            _ => ClusterStart::AlignedClusters,
        };
        for radius in radii
            .split(',')
            .filter_map(|r| r.trim().parse::<usize>().ok())
        {
            let clustered = ClusteredMbd {
                clusters: count,
                smoothing: LabelSmoothing { radius, falloff },
                start,
                options: options.clone(),
                polish: None,
            };
            let (fit, wall, cpu) = measure(|| {
                clustered
                    .fit_clusters(f, &cpca, &NoProgress)
                    .expect("clustered mbd")
            });
            let (model, report) = (fit.model, fit.solve);
            add(
                format!(
                    "MBD on CPCA's clusters, radius {radius}, falloff {falloff}, {start:?} start (≤ {} kernels at a point)",
                    model.basis_kernels().max_support()
                ),
                report.history.len().to_string(),
                wall,
                cpu,
                &model,
                moving(&model),
            );
            if let Some((polished, name, wall, cpu)) = polished(f, model) {
                add(
                    format!("MBD on CPCA's clusters, radius {radius}, {name}"),
                    "–".into(),
                    wall,
                    cpu,
                    &polished,
                    moving(&polished),
                );
            }
        }
    }
    if enabled("CMBD-RELABEL") {
        // Clustered MBD, then rounds of: every valid voxel relabelled to the kernel whose
        // fitted basis captures most of its energy, kernels rebuilt, the solve restarted from
        // the fitted bases.
        let radius = env_or("MBD_RELABEL_RADIUS", 2usize);
        let smoothing = LabelSmoothing {
            radius,
            falloff: env_or("MBD_FALLOFF", 0.5),
        };
        let rounds = env_or("MBD_RELABEL_ROUNDS", 2usize);
        let clustered = ClusteredMbd {
            clusters: count,
            smoothing,
            start: ClusterStart::AlignedClusters,
            options: options.clone(),
            polish: None,
        };
        let (fit, _, _) = measure(|| {
            clustered
                .fit_clusters(f, &cpca, &NoProgress)
                .expect("clustered mbd")
        });
        let mut model = fit.model;
        for round in 1..=rounds {
            let ((next, report), wall, cpu) = measure(|| {
                let labels = relabelled(f, &valid, &model);
                let kernels = LabelKernels::new(
                    f.dims(),
                    f.bounds(),
                    &labels,
                    model.basis().dim().0,
                    Some(&valid),
                    &smoothing,
                )
                .expect("kernels");
                let coefficients =
                    prt_kernels::HatGrid::new(f.dims(), voxel_centre_box(f)).expect("hat");
                solve_from_basis(
                    f,
                    coefficients,
                    kernels,
                    model.basis(),
                    &options,
                    &NoProgress,
                )
                .expect("relabelled solve")
            });
            let moved = next
                .basis_kernels()
                .labels()
                .iter()
                .zip(model.basis_kernels().labels())
                .filter(|(a, b)| a != b)
                .count();
            add(
                format!(
                    "MBD on CPCA's clusters, radius {radius}, relabelled ×{round} ({moved} voxels moved)"
                ),
                report.history.len().to_string(),
                wall,
                cpu,
                &next,
                moving(&next),
            );
            model = next;
        }
    }
    let cpca_error = rows
        .iter()
        .find(|r| r.name.starts_with("CPCA"))
        .map(|r| r.relative_mse);
    let mut table = Table::new(&[
        "method",
        "iterations",
        "wall (CPU) s",
        "relative MSE",
        "/ CPCA",
        "seam at CPCA's clusters: excess (ratio)",
        "seam at the hat cells: excess (ratio)",
        "projection seam ratio at CPCA's clusters",
        "projection seam ratio at BPCA's blocks",
    ]);
    for r in &rows {
        table.row(vec![
            r.name.clone(),
            r.iterations.clone(),
            format!("{:.1} ({:.1})", r.wall, r.cpu),
            format!("{:.3e}", r.relative_mse),
            cpca_error.map_or("–".into(), |c| format!("{:.2}", r.relative_mse / c)),
            format!("{:.2e} ({:.2})", r.seams[0].excess(), r.seams[0].ratio()),
            format!("{:.2e} ({:.2})", r.seams[1].excess(), r.seams[1].ratio()),
            format!("{:.2}", r.projection[0]),
            format!("{:.2}", r.projection[1]),
        ]);
    }
    println!("{}", table.markdown());
    println!("load average after: {}", load_average());
}
