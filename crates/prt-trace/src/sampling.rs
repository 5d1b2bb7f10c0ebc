//! Direction sets: randomly rotated icosahedra (a spherical 5-design) for the sphere, scrambled
//! Sobol' points mapped to the cosine-weighted hemisphere for the surface cache.

use glam::{Quat, Vec3};

/// Directions per icosahedron.
pub(crate) const ICOSA: usize = 12;

/// The 12 unit vertices of a regular icosahedron. They form a spherical 5-design: their mean of
/// any polynomial of degree <= 5 equals its mean over the sphere, so for SH of order 3 (degree
/// <= 2, products of degree <= 4) the rule `4π/12 Σ Y_i Y_j` is exactly the identity.
pub(crate) fn icosahedron() -> [Vec3; ICOSA] {
    let phi = (1.0 + 5f32.sqrt()) / 2.0;
    let raw = [
        (-1.0, phi, 0.0),
        (1.0, phi, 0.0),
        (-1.0, -phi, 0.0),
        (1.0, -phi, 0.0),
        (0.0, -1.0, phi),
        (0.0, 1.0, phi),
        (0.0, -1.0, -phi),
        (0.0, 1.0, -phi),
        (phi, 0.0, -1.0),
        (phi, 0.0, 1.0),
        (-phi, 0.0, -1.0),
        (-phi, 0.0, 1.0),
    ];
    raw.map(|(x, y, z)| Vec3::new(x, y, z).normalize())
}

/// SplitMix64 finaliser: decorrelates (seed, stream, index) into an Owen-scramble seed.
#[inline]
pub(crate) fn hash_seed(seed: u64, stream: u64, index: u64) -> u32 {
    let mut z = seed
        .wrapping_add(stream.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add(index.wrapping_mul(0xD1B5_4A32_D192_ED03));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) as u32
}

/// Uniform random rotation from three uniforms (Shoemake, "Uniform random rotations", 1992).
#[inline]
pub(crate) fn rotation_from_uniforms(u1: f32, u2: f32, u3: f32) -> Quat {
    let tau = std::f32::consts::TAU;
    let a = (1.0 - u1).max(0.0).sqrt();
    let b = u1.max(0.0).sqrt();
    Quat::from_xyzw(
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
        b * (tau * u3).cos(),
    )
    .normalize()
}

/// The rotation of icosahedron `group` of a point's direction set: Owen-scrambled Sobol'
/// points over the rotation group, so that successive groups stratify the rotations.
#[inline]
pub(crate) fn group_rotation(group: u32, scramble: u32) -> Quat {
    let [u1, u2, u3, _] = sobol_burley::sample_4d(group, 0, scramble);
    rotation_from_uniforms(u1, u2, u3)
}

/// Cosine-weighted direction about `n` from two uniforms (concentric disk mapping, Shirley and
/// Chiu 1997); pdf `cos θ / π`.
#[inline]
pub(crate) fn cosine_hemisphere(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let a = 2.0 * u1 - 1.0;
    let b = 2.0 * u2 - 1.0;
    let (r, phi) = if a == 0.0 && b == 0.0 {
        (0.0, 0.0)
    } else if a.abs() > b.abs() {
        (a, std::f32::consts::FRAC_PI_4 * (b / a))
    } else {
        (
            b,
            std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (a / b),
        )
    };
    let (x, y) = (r * phi.cos(), r * phi.sin());
    let z = (1.0 - x * x - y * y).max(0.0).sqrt();
    let (t, bt) = n.any_orthonormal_pair();
    (t * x + bt * y + n * z).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::{SH9, sh9};
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// The rotated icosahedron integrates every product Y_i Y_j exactly (5-design).
        #[test]
        fn rotated_icosahedron_is_exact_for_sh9_products(group in 0u32..4096, scramble in any::<u32>()) {
            let q = group_rotation(group, scramble);
            let mut gram = [[0.0f64; SH9]; SH9];
            for v in icosahedron() {
                let y = sh9(q * v);
                for i in 0..SH9 {
                    for j in 0..SH9 {
                        gram[i][j] += 4.0 * std::f64::consts::PI / 12.0 * (y[i] as f64) * (y[j] as f64);
                    }
                }
            }
            for i in 0..SH9 {
                for j in 0..SH9 {
                    let e = if i == j { 1.0 } else { 0.0 };
                    prop_assert!((gram[i][j] - e).abs() < 1e-5, "G[{}][{}] = {}", i, j, gram[i][j]);
                }
            }
        }

        /// Cosine-weighted directions lie in the hemisphere of n.
        #[test]
        fn cosine_directions_are_in_the_hemisphere(x in -1f32..1.0, y in -1f32..1.0, z in -1f32..1.0, u1 in 0f32..1.0, u2 in 0f32..1.0) {
            let n = Vec3::new(x, y, z);
            prop_assume!(n.length() > 0.1);
            let n = n.normalize();
            let d = cosine_hemisphere(n, u1, u2);
            prop_assert!((d.length() - 1.0).abs() < 1e-5);
            prop_assert!(d.dot(n) >= -1e-6);
        }
    }

    /// The mean of cos θ under the cosine-weighted pdf is 2/3; check within 5 standard errors.
    #[test]
    fn cosine_hemisphere_has_the_right_mean_cosine() {
        let n = Vec3::new(0.3, 0.9, -0.2).normalize();
        let count = 4096u32;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for i in 0..count {
            let [u1, u2, _, _] = sobol_burley::sample_4d(i, 0, 7);
            let c = cosine_hemisphere(n, u1, u2).dot(n) as f64;
            s += c;
            s2 += c * c;
        }
        let mean = s / count as f64;
        let var = s2 / count as f64 - mean * mean;
        // Var of cos under pdf cos/π: E[c²] - E[c]² = 1/2 - 4/9.
        assert!((var - (0.5 - 4.0 / 9.0)).abs() < 0.01, "variance {var}");
        let se = (var / count as f64).sqrt();
        assert!((mean - 2.0 / 3.0).abs() < 5.0 * se, "mean {mean}, se {se}");
    }
}
