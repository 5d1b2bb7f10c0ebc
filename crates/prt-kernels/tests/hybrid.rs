//! The hybrid ground-plane family.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{Aabb, KernelWeights, SpatialKernels};
use prt_kernels::{HybridKernels, KernelError};

fn terrain() -> Aabb {
    Aabb::new(
        Vec3::new(-512.0, -10.0, 0.0),
        Vec3::new(512.0, 90.0, 2048.0),
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Partition of unity with at most 4 kernels, constant along y, linear precision in x and z.
    #[test]
    fn laws(nx in 2usize..20, nz in 2usize..20, local in prop::array::uniform3(-0.2f32..1.2), y2 in -100.0f32..200.0, c in prop::array::uniform3(-2.0f32..2.0)) {
        let h = HybridKernels::new(nx, nz, terrain()).unwrap();
        let d = h.domain();
        let x = d.min + Vec3::from_array(local) * d.size();
        let (mut w, mut w2) = (KernelWeights::default(), KernelWeights::default());
        h.eval(x, &mut w).unwrap();
        h.eval(Vec3::new(x.x, y2, x.z), &mut w2).unwrap();
        prop_assert_eq!(&w, &w2);
        prop_assert!(w.len() <= 4 && h.max_support() == 4);
        prop_assert!((w.sum() - 1.0).abs() < 1e-5);
        let f = |p: Vec3| c[0] as f64 + c[1] as f64 * p.x as f64 + c[2] as f64 * p.z as f64;
        let got: f64 = w.iter().map(|(i, wi)| wi as f64 * f(h.centre(i as usize).unwrap())).sum();
        let want = f(d.clamp(x));
        prop_assert!((got - want).abs() < 1e-6 * 8192.0, "got {got} want {want}");
        // The support cell is the column, the same at every height.
        prop_assert_eq!(h.support_cell(x), h.support_cell(Vec3::new(x.x, y2, x.z)));
        let [cx, cz] = h.column_of(x).unwrap();
        prop_assert_eq!(h.support_cell(x), Some(cx + (nx - 1) * cz));
    }
}

#[test]
fn pairs_with_a_coefficient_grid_over_the_same_box() {
    let h = HybridKernels::new(9, 33, terrain()).unwrap();
    assert_eq!((h.len(), h.num_support_cells()), (9 * 33, 8 * 32));
    let coefficients = h.coefficient_grid([65, 5, 257]).unwrap();
    assert_eq!(coefficients.domain(), h.domain());
    assert_eq!(coefficients.max_support(), 8);
    // Node (i, k) at height centre: index i + nx * k.
    assert_eq!(
        h.centre(2 + 9 * 3),
        Some(Vec3::new(-512.0 + 2.0 * 128.0, 40.0, 3.0 * 64.0))
    );
    assert_eq!(
        h.eval_local(Vec3::new(0.0, 0.0, 0.0))
            .unwrap()
            .indices()
            .len(),
        4
    );
}

#[test]
fn invalid_hybrid_grids_are_typed_errors() {
    assert_eq!(
        HybridKernels::new(1, 5, terrain()),
        Err(KernelError::TooFewNodes {
            axis: 0,
            nodes: 1,
            min: 2
        })
    );
    assert_eq!(
        HybridKernels::new(5, 1, terrain()),
        Err(KernelError::TooFewNodes {
            axis: 2,
            nodes: 1,
            min: 2
        })
    );
    assert_eq!(
        HybridKernels::new(0, 5, terrain()),
        Err(KernelError::NoNodes { axis: 0 })
    );
    // Flat in y is fine (a height field's ground plane); flat in x is not.
    assert!(HybridKernels::new(3, 3, Aabb::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0))).is_ok());
    assert_eq!(
        HybridKernels::new(3, 3, Aabb::new(Vec3::ZERO, Vec3::new(0.0, 1.0, 1.0))),
        Err(KernelError::DegenerateAxis { axis: 0, nodes: 3 })
    );
}
