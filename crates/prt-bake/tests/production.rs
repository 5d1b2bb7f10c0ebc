//! The production configuration: the irradiance target's normalisation, the fill of invalid
//! voxels, and a small fit → write → read round trip on the built-in outdoor scene within the
//! 8-bit quantisation bound, with typed errors for damaged containers.

mod common;

use common::scratch;

use prt_bake::container::ContainerError;
use prt_bake::production::{
    IRRADIANCE_L1_DIM, ProductionConfig, ProductionContents, ProductionError, fill_invalid,
    fit_production, irradiance_l1, read_production, write_production,
};
use prt_core::{Aabb, FieldModel, GridField, NoProgress, glam::Vec3};
use prt_sphere::Sky;
use prt_texture::container::{MANIFEST_FILE, Manifest};
use prt_texture::{Encoding, Limits};
use prt_trace::{BakeOptions, Scene, TransferBaker, TransferVolume};

fn bake(scene: &Scene, resolution: [usize; 3], bounds: Aabb) -> TransferVolume {
    let options = BakeOptions {
        resolution,
        bounds: Some(bounds),
        margin: 20.0,
        rays_per_voxel: 24,
        cache_rays: 8,
        seed: 3,
        ..BakeOptions::default()
    };
    TransferBaker::new(scene, options)
        .and_then(|baker| baker.bake(&NoProgress))
        .expect("bake")
}

#[test]
fn irradiance_of_a_constant_sky_on_open_ground_is_pi_times_radiance() {
    // No geometry: every voxel sees the whole constant sky, so the irradiance on any normal is
    // π L and the L1 bands are zero.
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let volume = bake(&Scene::empty(), [2, 2, 2], bounds);
    let rgb = [0.5f32, 1.0, 2.0];
    let target = irradiance_l1(&volume.field, &Sky::constant(rgb)).expect("target");
    assert_eq!(target.dim(), IRRADIANCE_L1_DIM);
    let y0 = 0.5 / std::f32::consts::PI.sqrt();
    for v in 0..target.num_voxels() {
        let e = target.voxel(v);
        for (c, &radiance) in rgb.iter().enumerate() {
            let irradiance = e[4 * c] * y0;
            assert!((irradiance - std::f32::consts::PI * radiance).abs() < 1e-4 * radiance);
            assert!(e[4 * c + 1..4 * c + 4].iter().all(|x| x.abs() < 1e-5));
        }
    }
    let not_transfer =
        GridField::from_data([1, 1, 1], bounds, ndarray::Array2::zeros((1, 12))).expect("field");
    assert!(matches!(
        irradiance_l1(&not_transfer, &Sky::default()),
        Err(ProductionError::InvalidInput { .. })
    ));
}

#[test]
fn fill_keeps_valid_voxels_and_reaches_every_invalid_one() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::new(4.0, 1.0, 1.0));
    let data = ndarray::Array2::from_shape_fn((4, 2), |(v, d)| (v * 2 + d) as f32);
    let field = GridField::from_data([4, 1, 1], bounds, data).expect("field");
    let filled = fill_invalid(&field, &[false, true, false, false]).expect("fill");
    assert_eq!(filled.voxel(1), field.voxel(1));
    // Voxel 0 and 2 take voxel 1's value, then voxel 3 takes voxel 2's.
    for v in [0, 2, 3] {
        assert_eq!(filled.voxel(v), field.voxel(1));
    }
    assert!(matches!(
        fill_invalid(&field, &[false; 4]),
        Err(ProductionError::InvalidInput { .. })
    ));
    assert!(matches!(
        fill_invalid(&field, &[true; 3]),
        Err(ProductionError::InvalidInput { .. })
    ));
}

#[test]
fn production_fit_writes_and_reads_back_within_the_8_bit_bound() {
    // A corner of the outdoor town with a building, 8 × 6 × 8 voxels.
    let bounds = Aabb::new(Vec3::new(28.0, -1.0, 22.0), Vec3::new(44.0, 11.0, 38.0));
    let volume = bake(&Scene::outdoor_town(), [8, 6, 8], bounds);
    let sky = Sky::default();
    let target = irradiance_l1(&volume.field, &sky).expect("target");
    let target = fill_invalid(&target, &volume.valid).expect("fill");
    let mut config = ProductionConfig::for_grid(target.dims());
    assert_eq!(config.rank, 3);
    assert_eq!(config.coefficient_nodes, [4, 6, 4]);
    assert_eq!(config.basis_nodes, [2, 2]);
    config.solver.max_iterations = 8;
    let fit = fit_production(&target, &config, &NoProgress).expect("fit");
    let error = prt_mbd::evaluate(&fit.model, &target, &prt_mbd::EvalOptions::default())
        .expect("evaluate")
        .relative_mse;
    assert!(error < 0.05, "relative MSE {error}");

    let folder = scratch("production");
    let contents = ProductionContents {
        model: &fit.model,
        grid: target.dims(),
        scene: "outdoor town corner",
        sky: &sky,
        encoding: Encoding::Unorm8,
    };
    let report = write_production(&folder, &contents).expect("write");
    let back = read_production(&folder, &Limits::default()).expect("read");
    assert_eq!(back.grid, target.dims());
    assert_eq!(back.sky, sky);
    assert_eq!(back.encoding, Encoding::Unorm8);
    // Texels: 4 × 6 × 4 RGBA8 coefficients and 2 × 2 nodes × 9 RGBA8 basis texels.
    assert_eq!(back.texel_bytes(), 4 * 6 * 4 * 4 + 2 * 2 * 9 * 4);
    assert!(report.total_bytes > back.texel_bytes());

    // The bound of f̂ = Σ_l c_l b_l under half-step errors δc, δb (hats are a partition of
    // unity, so interpolated values and errors stay within the node bounds).
    let half_step = |name: &str, channel: usize| {
        let entry = back
            .manifest
            .arrays
            .iter()
            .find(|a| a.name == name)
            .expect("array");
        entry.range(channel).half_step(Encoding::Unorm8)
    };
    let rank = 3;
    let max_c: Vec<f32> = (0..rank)
        .map(|l| {
            fit.model
                .coefficients()
                .column(l)
                .iter()
                .fold(0.0f32, |m, x| m.max(x.abs()))
        })
        .collect();
    let basis = fit.model.basis();
    let bound: Vec<f32> = (0..IRRADIANCE_L1_DIM)
        .map(|d| {
            (0..rank)
                .map(|l| {
                    let max_b = basis
                        .slice(ndarray::s![.., l, d])
                        .iter()
                        .fold(0.0f32, |m, x| m.max(x.abs()));
                    let (hc, hb) = (half_step("coefficients", l), half_step("basis", l * 12 + d));
                    hc * max_b + max_c[l] * hb + hc * hb
                })
                .sum::<f32>()
                * 1.001
                + 1e-5
        })
        .collect();
    let (mut a, mut b) = ([0.0f32; 12], [0.0f32; 12]);
    for k in 0..200 {
        let t = Vec3::new(
            (k as f32 * 0.618_034).fract(),
            (k as f32 * 0.414_214).fract(),
            (k as f32 * 0.732_051).fract(),
        );
        let x = bounds.min + t * bounds.size();
        fit.model.eval(x, &mut a).expect("eval");
        back.model.eval(x, &mut b).expect("eval");
        for d in 0..12 {
            assert!(
                (a[d] - b[d]).abs() <= bound[d],
                "{x} {d}: {} vs {}",
                a[d],
                b[d]
            );
        }
    }

    // Damaged containers are typed errors.
    let manifest_path = folder.join(MANIFEST_FILE);
    let json = std::fs::read(&manifest_path).expect("manifest");
    let mut manifest = Manifest::from_json(&json, &Limits::default()).expect("manifest");
    manifest
        .attributes
        .insert("rank".into(), serde_json::json!(4));
    std::fs::write(&manifest_path, manifest.to_json().expect("json")).expect("write");
    assert!(matches!(
        read_production(&folder, &Limits::default()),
        Err(ProductionError::Container(ContainerError::Inconsistent(_)))
    ));
    manifest
        .attributes
        .insert("rank".into(), serde_json::json!(3));
    manifest
        .attributes
        .insert("sky".into(), serde_json::json!([1, 2]));
    std::fs::write(&manifest_path, manifest.to_json().expect("json")).expect("write");
    assert!(matches!(
        read_production(&folder, &Limits::default()),
        Err(ProductionError::Container(ContainerError::Inconsistent(_)))
    ));
    std::fs::write(&manifest_path, &json).expect("write");
    assert!(read_production(&folder, &Limits::default()).is_ok());
    let tiny = Limits {
        max_bytes: 64,
        ..Limits::default()
    };
    assert!(matches!(
        read_production(&folder, &tiny),
        Err(ProductionError::Container(ContainerError::Texture(_)))
    ));
    std::fs::remove_file(folder.join("basis.ktx2")).expect("remove");
    assert!(matches!(
        read_production(&folder, &Limits::default()),
        Err(ProductionError::Container(ContainerError::Texture(_)))
    ));
    // A container of another kind is refused by name.
    assert!(prt_bake::container::read_container(&folder, &Limits::default()).is_err());
    let _ = std::fs::remove_dir_all(&folder);
}
