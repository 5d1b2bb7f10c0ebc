//! The example program, run as a test: the container read back evaluates to the model in memory
//! within the f16 quantisation bound.

#[path = "../examples/cornell_round_trip.rs"]
mod example;

use prt_core::FieldModel;
use prt_mbd::MbdModel;
use prt_texture::Encoding;

#[test]
fn the_cornell_box_survives_the_round_trip_through_its_container() {
    let out = std::env::temp_dir().join(format!("prt-bake-example-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let trip = example::run(&out).expect("the example runs");
    assert_eq!(trip.container.encoding, Encoding::F16);
    assert_eq!(trip.container.attribute_str("scene"), Some("cornell_box"));
    assert_eq!(trip.container.model.rank(), 4);
    assert_eq!(trip.container.model.dim(), 324);
    assert_eq!(trip.container.grid, [8, 8, 8]);
    assert!(trip.container.valid.iter().any(|v| *v));
    // The kernels are rebuilt exactly from the manifest.
    assert_eq!(
        trip.container.model.coefficient_kernels(),
        trip.model.coefficient_kernels()
    );
    assert_eq!(
        trip.container.model.basis_kernels(),
        trip.model.basis_kernels()
    );

    // f16 stores each coefficient and basis value within a relative 2⁻¹¹ (plus 2⁻²⁵ for
    // subnormals), so f̂ = Σ_l c_l b_l moves by at most (2u + u²)·Σ_l |c_l||b_l|, which the model
    // with absolute values evaluates exactly (hat weights are non-negative).
    let u = 2f32.powi(-11);
    let magnitude = MbdModel::new(
        trip.model.coefficient_kernels().clone(),
        trip.model.basis_kernels().clone(),
        trip.model.coefficients().mapv(f32::abs) + 2f32.powi(-25),
        trip.model.basis().mapv(f32::abs) + 2f32.powi(-25),
    )
    .expect("model");
    let mut bound = vec![0.0; magnitude.dim()];
    magnitude.eval(trip.point, &mut bound).expect("eval");
    let mut nonzero = 0;
    for (d, ((a, b), m)) in trip
        .in_memory
        .iter()
        .zip(&trip.read_back)
        .zip(&bound)
        .enumerate()
    {
        let allowed = (2.0 * u + u * u) * m * 1.001 + 1e-7;
        assert!(
            (a - b).abs() <= allowed,
            "component {d}: {a} vs {b} (bound {allowed})"
        );
        nonzero += usize::from(*a != 0.0);
    }
    assert!(nonzero > 0, "f̂ is zero at the centre of the box");
    let _ = std::fs::remove_dir_all(out);
}
