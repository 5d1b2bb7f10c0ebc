//! MBD's coarse start (`Mbd::coarse_start`) against the paper's start and against clustered
//! PCA, on the valid voxels of a traced volume (the masked fits of `prt bake --layout sparse`):
//! solve time and error per (levels, coarse iterations, full-resolution iterations).
//!
//! ```text
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 128 --layout sparse --keep-volumes always --out /tmp/sponza128
//! cargo run --release -p prt-benches --bin mbd_coarse_start -- --volumes /tmp/sponza128/volumes
//! ```
//!
//! `--volumes` reads a bake's kept volumes (its traced field in f16 and its validity); without
//! it the field is `--field` / `--n`'s, valid where non-zero.
//! The error is `prt_mbd::evaluate`'s relative MSE (the bake report's, 4 jittered samples per
//! voxel over the whole box, invalid voxels included as zeros). Every fit is rank 8 on 5³ basis
//! nodes with the bake's solver options; the load average is printed before and after.

use std::path::PathBuf;

use clap::Parser;
use prt_bake::volumes::read_volumes;
use prt_benches::Table;
use prt_benches::mbd::{Cost, FieldArgs, basis_nodes};
use prt_benches::{large_file_limits, load_average};
use prt_core::NoProgress;
use prt_mbd::{Basis, ClusteredPca, CoarseStart, EvalOptions, Mbd, SolverOptions, evaluate};

#[derive(Debug, Parser)]
#[command(about = "MBD's coarse start against the paper's start and clustered PCA")]
struct Cli {
    #[command(flatten)]
    field: FieldArgs,
    /// A bake's kept volumes (`prt bake --keep-volumes always`, DIR/volumes).
    #[arg(long)]
    volumes: Option<PathBuf>,
    /// Rank L.
    #[arg(long, default_value_t = 8)]
    rank: usize,
    /// Basis nodes per axis (clusters: their product).
    #[arg(long, default_value_t = 5)]
    nodes: usize,
    /// Full-resolution iteration caps of the coarse-start rows (0: the coarse basis and
    /// per-voxel least-squares coefficients only).
    #[arg(long, value_delimiter = ',', default_value = "0,8,12,16,24")]
    fine: Vec<usize>,
    /// Coarse levels of the coarse-start rows.
    #[arg(long, value_delimiter = ',', default_value = "1")]
    levels: Vec<usize>,
    /// Iteration caps of each coarse solve.
    #[arg(long, value_delimiter = ',', default_value = "32,64")]
    coarse_iterations: Vec<usize>,
    /// Iteration cap of the paper's start (the bake's default).
    #[arg(long, default_value_t = 64)]
    iterations: usize,
}

fn main() {
    let cli = Cli::parse();
    let (name, field, valid) = match &cli.volumes {
        Some(folder) => {
            let mut kept = read_volumes(folder, &large_file_limits()).expect("kept volumes");
            let (_, field) = kept.volumes.swap_remove(0);
            (format!("{}", folder.display()), field, kept.valid)
        }
        None => {
            let input = cli.field.load();
            let valid = input
                .valid
                .unwrap_or_else(|| vec![true; input.field.num_voxels()]);
            (input.name, input.field, valid)
        }
    };
    let field = &field;
    let nodes = basis_nodes(field, cli.nodes);
    println!(
        "{}: rank {}, basis nodes {nodes:?}, {} valid voxels, {} threads, load average before {}",
        name,
        cli.rank,
        valid.iter().filter(|v| **v).count(),
        rayon::current_num_threads(),
        load_average()
    );
    let eval = EvalOptions::default();
    let mut table = Table::new(&[
        "method",
        "levels",
        "coarse cap / full iterations",
        "coarse s",
        "full-resolution s",
        "wall s",
        "CPU s",
        "relative MSE",
    ]);
    let mbd = |levels: usize, coarse: usize, full: usize| Mbd {
        solver: SolverOptions {
            max_iterations: full,
            ..SolverOptions::default()
        },
        coarse_start: (levels > 0).then_some(CoarseStart {
            levels,
            iterations: coarse,
        }),
        ..Mbd::new(cli.rank, Basis::HatGrid { nodes })
    };
    let mut runs = vec![(0, 0, cli.iterations)];
    for &levels in &cli.levels {
        for &coarse in &cli.coarse_iterations {
            runs.extend(cli.fine.iter().map(|&full| (levels, coarse, full)));
        }
    }
    for (levels, coarse, full) in runs {
        let (fit, cost) =
            Cost::measure(|| mbd(levels, coarse, full).fit_masked(field, &valid, &NoProgress));
        let fit = fit.expect("MBD fit");
        let error = evaluate(&fit.model, field, &eval).expect("evaluate");
        let coarse_iterations = if levels > 0 {
            coarse.to_string()
        } else {
            "–".into()
        };
        table.row(vec![
            "MBD".into(),
            levels.to_string(),
            format!("{coarse_iterations} / {}", fit.solve.history.len()),
            format!("{:.1}", fit.solve.coarse_seconds),
            format!("{:.1}", fit.solve.total_seconds()),
            format!("{:.1}", cost.wall),
            format!("{:.1}", cost.cpu),
            format!("{:.4e}", error.relative_mse),
        ]);
        println!("{}", table.markdown());
    }
    let clusters = nodes.iter().product();
    let (cpca, cost) = Cost::measure(|| {
        ClusteredPca::new(cli.rank, clusters).compress_masked(field, &valid, &NoProgress)
    });
    let cpca = cpca.expect("CPCA fit");
    let error = evaluate(&cpca, field, &eval).expect("evaluate");
    table.row(vec![
        format!("CPCA ({clusters} clusters)"),
        "–".into(),
        "–".into(),
        "–".into(),
        "–".into(),
        format!("{:.1}", cost.wall),
        format!("{:.1}", cost.cpu),
        format!("{:.4e}", error.relative_mse),
    ]);
    println!("{}", table.markdown());
    println!("load average after {}", load_average());
}
