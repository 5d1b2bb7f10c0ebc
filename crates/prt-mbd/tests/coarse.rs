//! `Mbd::coarse_start`: without a level it is the paper's start, bit for bit; masked, it never
//! reads invalid voxels; and it reaches the paper's error with fewer full-resolution iterations.

use prt_core::{Aabb, GridField, NoProgress};
use prt_mbd::{Basis, CoarseStart, EvalOptions, Mbd, SyntheticField, evaluate};

fn field(dims: [usize; 3], seed: u64) -> GridField {
    SyntheticField {
        dims,
        dim: 24,
        harmonics: 3,
        seed,
    }
    .build(Aabb::UNIT)
    .expect("synthetic field")
}

fn mbd(nodes: [usize; 3], iterations: usize, coarse_start: Option<CoarseStart>) -> Mbd {
    let mut mbd = Mbd::new(3, Basis::HatGrid { nodes });
    mbd.solver.max_iterations = iterations;
    mbd.coarse_start = coarse_start;
    mbd
}

#[test]
fn no_level_or_no_room_to_halve_is_the_papers_start() {
    let field = field([8, 6, 8], 3);
    let paper = mbd([3, 3, 3], 6, None)
        .fit(&field, &NoProgress)
        .expect("fit");
    for (nodes, levels) in [([3, 3, 3], 0), ([3, 4, 3], 1)] {
        let start = CoarseStart {
            levels,
            iterations: 4,
        };
        let paper = if nodes == [3, 3, 3] {
            paper.clone()
        } else {
            mbd(nodes, 6, None).fit(&field, &NoProgress).expect("fit")
        };
        let coarse = mbd(nodes, 6, Some(start))
            .fit(&field, &NoProgress)
            .expect("fit");
        assert_eq!(coarse.model.basis(), paper.model.basis());
        assert_eq!(coarse.model.coefficients(), paper.model.coefficients());
        assert_eq!(coarse.solve.coarse_seconds, 0.0);
    }
}

#[test]
fn a_masked_coarse_start_never_reads_invalid_voxels() {
    let field = field([10, 8, 6], 5);
    let valid: Vec<bool> = (0..field.num_voxels()).map(|v| v % 5 != 2).collect();
    let mut junk = field.clone();
    for (v, mut row) in junk.data_mut().outer_iter_mut().enumerate() {
        if !valid[v] {
            row.fill(1e3 + v as f32);
        }
    }
    let fit = |f: &GridField| {
        mbd([3, 3, 3], 4, Some(CoarseStart::default()))
            .fit_masked(f, &valid, &NoProgress)
            .expect("fit")
    };
    let (a, b) = (fit(&field), fit(&junk));
    assert!(a.solve.coarse_seconds > 0.0);
    assert_eq!(a.model.basis(), b.model.basis());
    assert_eq!(a.model.coefficients(), b.model.coefficients());
}

#[test]
fn a_coarse_start_reaches_the_papers_error_in_a_quarter_of_the_full_iterations() {
    let field = field([24, 24, 24], 7);
    let eval = EvalOptions::default();
    let error = |mbd: Mbd| {
        let fit = mbd.fit(&field, &NoProgress).expect("fit");
        evaluate(&fit.model, &field, &eval)
            .expect("evaluate")
            .relative_mse
    };
    let paper = error(mbd([4, 4, 4], 32, None));
    let coarse = error(mbd(
        [4, 4, 4],
        8,
        Some(CoarseStart {
            levels: 1,
            iterations: 32,
        }),
    ));
    println!(
        "relative MSE: paper's start, 32 iterations {paper:.4e}; coarse start, 8 {coarse:.4e}"
    );
    assert!(coarse <= 1.1 * paper, "{coarse:.4e} against {paper:.4e}");
}
