//! Lighting a compressed bake on its basis grid: a sky collapses each 324-D basis vector to
//! the few values a pixel needs, so a sky change costs a pass over nodes × rank, not voxels.

use ndarray::Array3;
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_sphere::Sky;
use prt_trace::TRANSFER_DIM;

use crate::BakeError;

/// SH coefficients per operator row and column (order 3).
const SH9: usize = 9;
/// Values of one 9 × 9 operator block of a transfer vector.
const BLOCK: usize = SH9 * SH9;

/// What the lit basis holds per basis vector: incident radiance as SH per colour channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum LitBasisTarget {
    /// Order-3 SH (9 coefficients) per channel, `[R 9 | G 9 | B 9]`: 27 values, what
    /// [`prt_trace::lit::incident_radiance`] gives for a transfer vector.
    #[default]
    Sh9Rgb,
    /// Linear SH (bands 0 and 1, 4 coefficients) per channel, `[R 4 | G 4 | B 4]`: 12 values.
    L1Rgb,
}

impl LitBasisTarget {
    /// SH coefficients kept per colour channel (9 or 4).
    pub fn coefficients_per_channel(self) -> usize {
        match self {
            LitBasisTarget::Sh9Rgb => SH9,
            LitBasisTarget::L1Rgb => 4,
        }
    }

    /// Values per lit basis vector (27 or 12).
    pub fn dim(self) -> usize {
        3 * self.coefficients_per_channel()
    }
}

/// How [`light_basis`] lights a model: the sky and the target.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LightBasisConfig {
    /// The distant lighting, as order-3 SH per channel.
    pub sky: Sky,
    /// What each lit basis vector holds.
    pub target: LitBasisTarget,
}

/// A model's basis lit by a sky: `b̃_{n,l} = M(sky) B_{n,l}` on every basis node.
///
/// Paired with the model's coefficients it is the lit model
/// `f̃(x) = Σ_l c_l(x) b̃_l(x)` (both trilinear hat sums); [`LitBasis::model`] builds it.
#[derive(Debug, Clone, PartialEq)]
pub struct LitBasis {
    /// The target the values follow.
    pub target: LitBasisTarget,
    /// `N × L × K` (basis node, basis vector, lit value; `K = target.dim()`).
    pub basis: Array3<f32>,
}

impl LitBasis {
    /// The lit model `f̃(x) = Σ_l c_l(x) b̃_l(x)`: `model`'s kernels and coefficients with this
    /// basis; evaluate it with [`prt_core::FieldModel::eval`]. `model` must be the one lit.
    pub fn model(
        &self,
        model: &MbdModel<HatGrid, HatGrid>,
    ) -> Result<MbdModel<HatGrid, HatGrid>, BakeError> {
        MbdModel::new(
            model.coefficient_kernels().clone(),
            model.basis_kernels().clone(),
            model.coefficients().clone(),
            self.basis.clone(),
        )
        .map_err(BakeError::Mbd)
    }
}

/// Lights every basis vector of `model` (324-D transfer, prt-trace's layout) by `config.sky`:
/// `b̃_{n,l}[c·k + i] = Σ_j (D_ij + T^c_ij) s^c_j` for the kept SH coefficients `i` of channel
/// `c`, exactly [`prt_trace::lit::incident_radiance`] applied to `B_{n,l}`, truncated to the target.
///
/// Each output reads 18 of the 324 inputs (one row of the direct block and one of the
/// channel's indirect block), so the pass costs `N·L·K·18` multiply-adds, f32 throughout (each
/// sum has 18 terms). Errors when the model's dimension is not 324.
pub fn light_basis(
    model: &MbdModel<HatGrid, HatGrid>,
    config: &LightBasisConfig,
) -> Result<LitBasis, BakeError> {
    let (nodes, rank, dim) = model.basis().dim();
    if dim != TRANSFER_DIM {
        return Err(BakeError::NotTransfer {
            expected: TRANSFER_DIM,
            got: dim,
        });
    }
    let target = config.target;
    let (k, out_dim) = (target.coefficients_per_channel(), target.dim());
    // `MbdModel::new` stores its tensors in standard layout.
    let input = model
        .basis()
        .as_slice()
        .expect("an MbdModel's basis is contiguous");
    let mut out = vec![0.0f32; nodes * rank * out_dim];
    let sky = &config.sky.sh;
    for (row, lit) in input
        .chunks_exact(TRANSFER_DIM)
        .zip(out.chunks_exact_mut(out_dim))
    {
        let direct = &row[..BLOCK];
        for (c, (channel_out, s)) in lit.chunks_exact_mut(k).zip(sky).enumerate() {
            let indirect = &row[(c + 1) * BLOCK..(c + 2) * BLOCK];
            for (i, value) in channel_out.iter_mut().enumerate() {
                let d = &direct[i * SH9..(i + 1) * SH9];
                let t = &indirect[i * SH9..(i + 1) * SH9];
                let mut sum = 0.0f32;
                for j in 0..SH9 {
                    sum += (d[j] + t[j]) * s[j];
                }
                *value = sum;
            }
        }
    }
    let basis = Array3::from_shape_vec((nodes, rank, out_dim), out)
        .expect("the output holds nodes × rank × target values");
    Ok(LitBasis { target, basis })
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use ndarray::Array2;
    use proptest::prelude::*;
    use prt_core::{Aabb, FieldModel, SpatialKernels};

    use super::*;

    /// A random rank-`rank` 324-D model on a 4×3×5 coefficient grid and a 3×2×2 basis grid.
    fn random_model(seed: u64, rank: usize) -> MbdModel<HatGrid, HatGrid> {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let domain = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(3.0, 1.5, 4.0));
        let coefficient_kernels = HatGrid::new([4, 3, 5], domain).unwrap();
        let basis_kernels = HatGrid::new([3, 2, 2], domain).unwrap();
        let coefficients = Array2::from_shape_fn((60, rank), |_| next());
        let basis = Array3::from_shape_fn((12, rank, TRANSFER_DIM), |_| next());
        MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis).unwrap()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        /// Linearity: lighting the basis and then reconstructing equals reconstructing the
        /// transfer and then lighting it, to float rounding.
        #[test]
        fn lighting_the_basis_commutes_with_reconstruction(
            seed in any::<u64>(),
            rank in 1usize..6,
            point in prop::array::uniform3(-0.2f32..1.2),
            degrees in 0.0f32..360.0,
            l1 in any::<bool>(),
        ) {
            let model = random_model(seed, rank);
            let sky = Sky::default().rotated_about_y(degrees);
            let target = if l1 { LitBasisTarget::L1Rgb } else { LitBasisTarget::Sh9Rgb };
            let lit = light_basis(&model, &LightBasisConfig { sky, target }).unwrap();
            let lit_model = lit.model(&model).unwrap();
            let domain = model.coefficient_kernels().domain();
            let x = domain.min + Vec3::from_array(point) * domain.size();
            let mut transfer = vec![0.0; TRANSFER_DIM];
            model.eval(x, &mut transfer).unwrap();
            let reference = prt_trace::lit::incident_radiance(&transfer, &sky);
            let mut got = vec![0.0; target.dim()];
            lit_model.eval(x, &mut got).unwrap();
            let k = target.coefficients_per_channel();
            // The scale of the sums: rounding is a few ulps of Σ|terms|.
            let magnitude: f32 = transfer.iter().map(|v| v.abs()).sum::<f32>()
                * sky.sh.as_flattened().iter().map(|v| v.abs()).fold(0.0, f32::max);
            for c in 0..3 {
                for i in 0..k {
                    let (a, b) = (got[c * k + i], reference[c][i]);
                    prop_assert!(
                        (a - b).abs() <= 1e-5 * magnitude.max(1.0),
                        "channel {c} coefficient {i}: lit {a}, reference {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_model_that_is_not_transfer_is_refused() {
        let model = random_model(1, 2);
        let (c, b, coefficients, basis) = model.into_parts();
        let short = basis.slice(ndarray::s![.., .., ..27]).to_owned();
        let model = MbdModel::new(c, b, coefficients, short).unwrap();
        assert!(light_basis(&model, &LightBasisConfig::default()).is_err());
    }
}
