//! Laws of `Sky`: what it evaluates to, how it turns, what it refuses.

use glam::{Mat3, Vec3};
use proptest::prelude::*;
use prt_sphere::{LatLongMap, Sky, SphereError};

fn unit(v: [f32; 3]) -> Option<Vec3> {
    let v = Vec3::from(v);
    (v.length() > 0.1).then(|| v.normalize())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The rotated sky's radiance towards `r ω` is the original's towards `ω`.
    #[test]
    fn rotation_moves_radiance_with_the_directions(
        axis in prop::array::uniform3(-1.0f32..1.0),
        angle in -3.2f32..3.2,
        dir in prop::array::uniform3(-1.0f32..1.0),
    ) {
        let (Some(axis), Some(dir)) = (unit(axis), unit(dir)) else { return Ok(()); };
        let r = Mat3::from_axis_angle(axis, angle);
        let sky = Sky::default();
        let turned = sky.rotated(r).unwrap();
        let diff = (turned.radiance(r * dir) - sky.radiance(dir)).abs().max_element();
        prop_assert!(diff < 1e-4, "difference {diff}");
    }
}

#[test]
fn default_and_constant_skies_have_their_documented_radiance() {
    let sky = Sky::default();
    let c = Vec3::new(0.9, 1.0, 1.2);
    for dir in [Vec3::Y, -Vec3::Y, Vec3::X, Vec3::new(0.6, 0.8, 0.0)] {
        let want = c * (1.0 + 0.6 * dir.y);
        assert!(
            (sky.radiance(dir) - want).abs().max_element() < 1e-5,
            "{dir}"
        );
    }
    let grey = Sky::constant([2.0, 3.0, 4.0]);
    assert!(
        (grey.radiance(Vec3::Z) - Vec3::new(2.0, 3.0, 4.0))
            .abs()
            .max_element()
            < 1e-5
    );
    assert_eq!(
        Sky::default().rotated_about_y(90.0).radiance(Vec3::Y),
        sky.radiance(Vec3::Y)
    );
}

#[test]
fn a_constant_map_projects_to_a_constant_sky() {
    let map = LatLongMap::from_fn(256, 128, |_| Vec3::new(1.0, 0.5, 0.25)).unwrap();
    let sky = Sky::from_latlong(&map).unwrap();
    let want = Sky::constant([1.0, 0.5, 0.25]);
    for c in 0..3 {
        for j in 0..9 {
            assert!(
                (sky.sh[c][j] - want.sh[c][j]).abs() < 1e-3,
                "{c} {j}: {}",
                sky.sh[c][j]
            );
        }
    }
}

#[test]
fn non_finite_coefficients_and_non_rotations_are_refused() {
    let mut sh = Sky::default().sh;
    sh[1][4] = f32::NAN;
    assert_eq!(
        Sky::from_coefficients(sh),
        Err(SphereError::NonFinite {
            what: "sky SH coefficient",
            index: 13
        })
    );
    assert!(
        Sky::default()
            .rotated(Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0)))
            .is_err()
    );
}

/// Without a sun, the closed-form SH of `Sky::sun_sky` equals the numerical projection of the
/// documented sky gradient and lit ground.
#[test]
fn sun_sky_matches_the_projection_of_its_formula() {
    use prt_sphere::SunSky;
    let params = SunSky {
        sun: [0.0; 3],
        ground_albedo: 0.3,
        ..SunSky::default()
    };
    let (zenith, horizon) = (Vec3::from(params.zenith), Vec3::from(params.horizon));
    let ground_irradiance =
        std::f32::consts::PI * horizon + 2.0 * std::f32::consts::FRAC_PI_3 * (zenith - horizon);
    let ground = params.ground_albedo * ground_irradiance / std::f32::consts::PI;
    let map = LatLongMap::from_fn(1024, 512, |d| {
        if d.y > 0.0 {
            horizon + (zenith - horizon) * d.y
        } else {
            ground
        }
    })
    .unwrap();
    let numeric = Sky::from_latlong(&map).unwrap();
    let closed = Sky::sun_sky(&params).unwrap();
    for c in 0..3 {
        for j in 0..9 {
            let (a, b) = (closed.sh[c][j], numeric.sh[c][j]);
            assert!(
                (a - b).abs() < 2e-3,
                "channel {c} coefficient {j}: {a} vs {b}"
            );
        }
    }
}

/// The sun term is the exact projection of a directional light: `E · Y_j(s)` added to the sky.
#[test]
fn sun_sky_adds_the_sun_as_a_delta_and_refuses_bad_parameters() {
    use prt_sphere::{SunSky, eval_sh};
    let base = SunSky::default();
    let dark = Sky::sun_sky(&SunSky {
        sun: [0.0; 3],
        ground_albedo: 0.0,
        ..base
    })
    .unwrap();
    let lit = Sky::sun_sky(&SunSky {
        ground_albedo: 0.0,
        ..base
    })
    .unwrap();
    let s = base.sun_direction();
    assert!((s - Vec3::new(0.0, 0.5f32.sqrt(), 0.5f32.sqrt())).length() < 1e-6);
    let mut y = [0.0f32; 9];
    eval_sh(3, s, &mut y);
    for c in 0..3 {
        for j in 0..9 {
            let want = dark.sh[c][j] + base.sun[c] * y[j];
            assert!((lit.sh[c][j] - want).abs() < 1e-5);
        }
    }
    let nan = SunSky {
        elevation_deg: f32::NAN,
        ..base
    };
    assert!(matches!(
        Sky::sun_sky(&nan),
        Err(SphereError::NonFinite { index: 0, .. })
    ));
    let bright_ground = SunSky {
        ground_albedo: 1.5,
        ..base
    };
    assert!(matches!(
        Sky::sun_sky(&bright_ground),
        Err(SphereError::Invalid { .. })
    ));
}
