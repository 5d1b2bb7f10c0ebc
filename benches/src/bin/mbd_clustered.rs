//! MBD on smoothed clustered-PCA clusters (`prt_mbd::Basis::Clusters`) against MBD on the hat
//! grid, BPCA and CPCA, at rank `--rank` with `--nodes`³ basis nodes / blocks / clusters; every
//! MBD with the default solver (≤ `--iterations` iterations, `--tolerance` its stopping rule),
//! optionally followed by the exact polish (`--polish-iterations`).
//!
//! ```text
//! cargo run --release -p prt-benches --bin mbd_clustered -- --field sponza --n 48 --methods HAT,BPCA,CPCA,CMBD --radii 2
//! ```
//!
//! Methods (`--methods`, default `HAT,BPCA,CPCA,CMBD`): `HAT` (MBD on the hat grid), `CMBD`
//! (MBD on CPCA's clusters, once per smoothing radius in `--radii` with `--falloff`), `CPCA`,
//! `BPCA`, `WBPCA` (blocks of twice the size), `PCA` (global PCA: one basis everywhere, so it
//! has no seams and its seam ratios are the floor the field's own structure sets at each set of
//! boundaries) and `CPCA-MAJORITY` (a control: CPCA's labels after 1..=`--passes` rounds of a
//! majority filter over the valid 3³ neighbours, each cluster's subspace refitted: how much of
//! CPCA's lead comes from switching subspaces from voxel to voxel).
//!
//! Reported per method: iterations, wall and process CPU time (the `CMBD` rows exclude CPCA's
//! clustering, which the `CPCA` row times), relative MSE on jittered samples and its ratio to
//! CPCA's, the error seams (σ = 1 denoised, valid voxels) at CPCA's cluster boundaries and at
//! the hat grid's basis cells, and the basis-projection seam ratio (`prt_mbd::
//! projection_seam_ratio`, the report's seam view) at CPCA's clusters and at BPCA's blocks.
//! With `--polish-iterations` > 0 every MBD row is followed by the same model after the exact
//! polish, with the exact relative MSE before and after in its name; its time is the polish's
//! alone.

use clap::Parser;
use prt_benches::Table;
use prt_benches::load_average;
use prt_benches::mbd::{Cost, FieldArgs, basis_nodes, method_enabled};
use prt_core::{Compressor, FieldModel, GridField, NoProgress, SpatialKernels, resample_to_grid};
use prt_kernels::HatGrid;
use prt_mbd::expert::{
    PolishBasis, PolishStep, blur_valid, fit_on_clusters, kernel_labels, nonzero_voxels, polish,
    projection_residuals, residual_seam_ratio, trilinear_energy,
};
use prt_mbd::*;

#[derive(Debug, Parser)]
#[command(about = "MBD on smoothed CPCA clusters against the hat grid, BPCA and CPCA")]
struct Cli {
    #[command(flatten)]
    field: FieldArgs,
    /// Methods: HAT, CMBD, CPCA, BPCA, WBPCA, PCA, CPCA-MAJORITY.
    #[arg(long, value_delimiter = ',', default_value = "HAT,BPCA,CPCA,CMBD")]
    methods: Vec<String>,
    /// Rank L.
    #[arg(long, default_value_t = 8)]
    rank: usize,
    /// Basis nodes (blocks; their product: clusters) per axis.
    #[arg(long, default_value_t = 5)]
    nodes: usize,
    /// Solver iteration cap.
    #[arg(long, default_value_t = 128)]
    iterations: usize,
    /// Solver stopping tolerance [default: the solver's].
    #[arg(long)]
    tolerance: Option<f64>,
    /// Smoothing radii of the CMBD rows.
    #[arg(long, value_delimiter = ',', default_value = "0,1,2")]
    radii: Vec<usize>,
    /// Smoothing falloff of the CMBD rows.
    #[arg(long, default_value_t = 0.5)]
    falloff: f32,
    /// Majority-filter rounds of the CPCA-MAJORITY control.
    #[arg(long, default_value_t = 3)]
    passes: usize,
    /// Exact polish iterations after every MBD row (0: none).
    #[arg(long, default_value_t = 0)]
    polish_iterations: usize,
    /// The polish's stopping tolerance (0: every iteration).
    #[arg(long, default_value_t = 0.0)]
    polish_tolerance: f64,
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

struct Row {
    name: String,
    iterations: String,
    wall: f64,
    cpu: f64,
    relative_mse: f64,
    seams: [ErrorSeams; 2],
    /// Basis-projection seam ratio at CPCA's clusters and at BPCA's blocks.
    projection: [f64; 2],
}

/// `model` after the exact polish (none without `--polish-iterations`), with a name giving the
/// iterations and the exact relative MSE before and after, and the polish's cost.
fn polished<B: PolishBasis>(
    cli: &Cli,
    f: &GridField,
    model: MbdModel<HatGrid, B>,
) -> Option<(MbdModel<HatGrid, B>, String, Cost)> {
    if cli.polish_iterations == 0 {
        return None;
    }
    let options = PolishOptions {
        iterations: cli.polish_iterations,
        tolerance: cli.polish_tolerance,
        ..PolishOptions::default()
    };
    let ((model, report), cost) =
        Cost::measure(|| polish(f, model, &options, &NoProgress).expect("polish"));
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
        "+ {done} polish iterations (exact {:.3e} → {:.3e})",
        report.initial.relative_mse(),
        report.last().relative_mse()
    );
    Some((model, name, cost))
}

/// The per-voxel bases of a clustered model, for the projection seams.
fn clustered_basis(model: &PiecewisePcaModel) -> LocalBasis<'_> {
    LocalBasis::Clustered {
        labels: model.labels(),
        bases: model.bases(),
    }
}

/// The moving basis of an MBD model, for the projection seams.
fn moving<B: SpatialKernels>(model: &MbdModel<HatGrid, B>) -> LocalBasis<'_> {
    LocalBasis::Moving {
        kernels: model.basis_kernels(),
        basis: model.basis(),
    }
}

fn main() {
    let cli = Cli::parse();
    let enabled = |m: &str| method_enabled(&cli.methods, &[], m);
    let input = cli.field.load();
    let (f, l) = (&input.field, cli.rank);
    let valid = nonzero_voxels(f);
    let nodes = basis_nodes(f, cli.nodes);
    let count: usize = nodes.iter().product();
    println!(
        "{}; L = {l}, {count} basis nodes / clusters; load average before: {}",
        input.name,
        load_average()
    );
    let mut solver = SolverOptions {
        max_iterations: cli.iterations,
        ..SolverOptions::default()
    };
    if let Some(tolerance) = cli.tolerance {
        solver.tolerance = tolerance;
    }
    let hat = Mbd {
        solver: solver.clone(),
        ..Mbd::new(l, Basis::HatGrid { nodes })
    };
    let hat_kernels = HatGrid::new(nodes, prt_mbd::expert::basis_box(f)).expect("hat grid");
    let hat_labels = kernel_labels(&hat_kernels, f).expect("labels");
    // Fitted once: the CPCA row and every clustered MBD (which starts from its clusters).
    let (cpca, cpca_cost) = Cost::measure(|| {
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
    let (bpca, bpca_cost) = Cost::measure(|| {
        BlockPca {
            rank: l,
            blocks: nodes,
            window: 1.0,
            loss_weighting: None,
        }
        .compress(f, &NoProgress)
        .expect("bpca")
    });
    let block_labels = bpca.labels().to_vec();
    let smoothed = blur_valid(f, &valid, 1.0).expect("blur");
    let mut rows: Vec<Row> = Vec::new();
    let mut add = |name: String,
                   iterations: String,
                   cost: Cost,
                   model: &dyn FieldModel,
                   basis: LocalBasis<'_>| {
        let residuals = projection_residuals(&smoothed, &valid, &basis).expect("projection");
        let projection = [&cluster_labels, &block_labels].map(|labels| {
            residual_seam_ratio(&smoothed, &valid, labels, &residuals).expect("projection seams")
        });
        let e = evaluate(model, f, &EvalOptions::default()).expect("evaluate");
        let recon = resample_to_grid(model, f.dims(), f.bounds()).expect("resample");
        let seam = |labels: &[u32]| {
            error_seams(
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
            "{name}: {iterations} iterations, {:.1} s (CPU {:.1} s), relative MSE {:.3e}",
            cost.wall, cost.cpu, e.relative_mse
        );
        rows.push(Row {
            name,
            iterations,
            wall: cost.wall,
            cpu: cost.cpu,
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
            cpca_cost,
            &cpca,
            clustered_basis(&cpca),
        );
    }
    if enabled("CPCA-MAJORITY") {
        let mut labels = cluster_labels.clone();
        for pass in 1..=cli.passes {
            labels = majority_filter(f, &valid, &labels);
            let (model, cost) = Cost::measure(|| {
                ClusteredPca::with_labels(f, labels.clone(), l, &NoProgress).expect("cpca")
            });
            add(
                format!(
                    "control: CPCA's labels majority-filtered ×{pass} ({:.1} % on a boundary), bases refitted",
                    100.0 * boundary_share(f, &valid, &labels)
                ),
                "–".into(),
                cost,
                &model,
                clustered_basis(&model),
            );
        }
    }
    if enabled("HAT") {
        let (fit, cost) = Cost::measure(|| hat.fit(f, &NoProgress).expect("mbd"));
        add(
            format!("MBD, {count} hat kernels"),
            fit.solve.history.len().to_string(),
            cost,
            &fit.model,
            moving(&fit.model),
        );
        if let Some((polished, name, cost)) = polished(&cli, f, fit.model) {
            add(
                format!("MBD, {count} hat kernels, {name}"),
                "–".into(),
                cost,
                &polished,
                moving(&polished),
            );
        }
    }
    if enabled("BPCA") {
        add(
            "BPCA".into(),
            "–".into(),
            bpca_cost,
            &bpca,
            clustered_basis(&bpca),
        );
    }
    if enabled("PCA") {
        let (m, cost) =
            Cost::measure(|| GlobalPca { rank: l }.compress(f, &NoProgress).expect("pca"));
        add(
            "control: global PCA (no seams)".into(),
            "–".into(),
            cost,
            &m,
            clustered_basis(&m),
        );
    }
    if enabled("WBPCA") {
        let (m, cost) = Cost::measure(|| {
            BlockPca {
                rank: l,
                blocks: nodes,
                window: 2.0,
                loss_weighting: None,
            }
            .compress(f, &NoProgress)
            .expect("wbpca")
        });
        add("WBPCA".into(), "–".into(), cost, &m, clustered_basis(&m));
    }
    if enabled("CMBD") {
        for &radius in &cli.radii {
            let smoothing = LabelSmoothing {
                radius,
                falloff: cli.falloff,
            };
            let clustered = Mbd {
                solver: solver.clone(),
                ..Mbd::new(l, Basis::Clusters { count, smoothing })
            };
            let (fit, cost) = Cost::measure(|| {
                fit_on_clusters(&clustered, f, &cpca, &NoProgress).expect("clustered mbd")
            });
            add(
                format!(
                    "MBD on CPCA's clusters, radius {radius}, falloff {} (≤ {} kernels at a point)",
                    cli.falloff,
                    fit.model.basis_kernels().max_support()
                ),
                fit.solve.history.len().to_string(),
                cost,
                &fit.model,
                moving(&fit.model),
            );
            if let Some((polished, name, cost)) = polished(&cli, f, fit.model) {
                add(
                    format!("MBD on CPCA's clusters, radius {radius}, {name}"),
                    "–".into(),
                    cost,
                    &polished,
                    moving(&polished),
                );
            }
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
