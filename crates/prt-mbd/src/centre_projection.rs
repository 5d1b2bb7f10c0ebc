//! The centre projection of [`crate::Mbd::centre_projection`]: with the basis fitted, each
//! voxel's coefficients become the ridge least-squares projection of the voxel's own vector on
//! the basis at its centre, the step the streamed merge fits every voxel by
//! ([`StreamedMbd::project`]).

use ndarray::Array2;
use prt_core::GridField;
use prt_kernels::HatGrid;
use rayon::prelude::*;

use crate::{BasisKernels, MbdError, MbdModel, ProjectScratch, StreamedMbd};

/// `model` with the coefficients of every voxel `v` (`valid[v]`; `None`: all) replaced by
/// `argmin_c ‖B(x_v) c − f_v‖² + λ‖c‖²`, `B(x_v)` the basis at the voxel's centre (the other
/// voxels keep theirs). The voxel-centre values are what renders and exports read, and this
/// makes each of them the best its basis can do for that voxel alone: its error is the part of
/// its own vector outside the local subspace, never above the vector's own magnitude, as with
/// the PCA baselines' per-voxel projection, instead of carrying the stochastic solver's noise
/// and the pull of brighter neighbours.
///
/// # Errors
/// [`MbdError::InvalidOption`] for a basis other than a hat grid; [`MbdError::ShapeMismatch`]
/// when the model is not one coefficient row per voxel of `field` or the mask's length differs.
pub(crate) fn project_on_centres(
    field: &GridField,
    valid: Option<&[bool]>,
    model: MbdModel<HatGrid, BasisKernels>,
    lambda: f32,
) -> Result<MbdModel<HatGrid, BasisKernels>, MbdError> {
    let (coefficient_kernels, basis_kernels, coefficients, basis) = model.into_parts();
    let BasisKernels::HatGrid(hats) = &basis_kernels else {
        return Err(MbdError::InvalidOption {
            what: "centre_projection",
            why: "the centre projection needs Basis::HatGrid".into(),
        });
    };
    let (m, l) = coefficients.dim();
    if m != field.num_voxels() || valid.is_some_and(|v| v.len() != m) {
        return Err(MbdError::ShapeMismatch {
            what: "centre projection (one coefficient row and one mask entry per voxel)",
            expected: vec![field.num_voxels()],
            got: vec![m, valid.map_or(m, <[bool]>::len)],
        });
    }
    let projector = StreamedMbd::new(field.dims(), field.bounds(), hats.nodes(), basis, lambda)?;
    // MbdModel keeps its tensors in standard layout: a row-major copy.
    let mut rows: Vec<f32> = coefficients.iter().copied().collect();
    rows.par_chunks_mut(l).enumerate().try_for_each_init(
        ProjectScratch::default,
        |scratch, (v, out)| -> Result<(), MbdError> {
            if valid.is_none_or(|valid| valid[v]) {
                projector.project(field.coords(v), field.voxel(v), out, scratch)?;
            }
            Ok(())
        },
    )?;
    let coefficients =
        Array2::from_shape_vec((m, l), rows).map_err(|_| MbdError::ShapeMismatch {
            what: "coefficient tensor",
            expected: vec![m, l],
            got: vec![m, l],
        })?;
    MbdModel::new(
        coefficient_kernels,
        basis_kernels,
        coefficients,
        projector.basis().clone(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use proptest::prelude::*;
    use prt_core::Aabb;

    use crate::fit::{coefficient_kernels, hat_basis_on};

    type Model = MbdModel<HatGrid, BasisKernels>;

    const DIMS: [usize; 3] = [5, 4, 3];
    const D: usize = 6;
    const L: usize = 2;

    fn values(seed: u64, n: usize) -> Vec<f32> {
        let mut state = seed | 1;
        (0..n)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state % 2001) as f32 / 1000.0 - 1.0
            })
            .collect()
    }

    /// A random rank-2 model on a 5 × 4 × 3 field with a 2³ hat basis, and a field whose
    /// voxel magnitudes span four orders.
    fn setup(seed: u64) -> (GridField, Model) {
        let mut noise = values(seed, DIMS.iter().product::<usize>() * D).into_iter();
        let field = GridField::from_fn(DIMS, Aabb::UNIT, D, |p, out| {
            let scale = 10f32.powf(4.0 * p.x - 2.0);
            out.iter_mut()
                .for_each(|x| *x = scale * noise.next().unwrap_or(0.0));
        })
        .unwrap();
        let basis_kernels = hat_basis_on(DIMS, Aabb::UNIT, [2, 2, 2]).unwrap();
        let coefficient_kernels = coefficient_kernels(&field).unwrap();
        let m = field.num_voxels();
        let coefficients = Array2::from_shape_vec((m, L), values(seed ^ 7, m * L)).unwrap();
        let basis = Array3::from_shape_vec((8, L, D), values(seed ^ 11, 8 * L * D)).unwrap();
        let model = MbdModel::new(
            coefficient_kernels,
            BasisKernels::HatGrid(basis_kernels),
            coefficients,
            basis,
        )
        .unwrap();
        (field, model)
    }

    /// The basis at voxel `v`'s centre (`L × D`) and the model's value there.
    fn at_centre(model: &Model, field: &GridField, v: usize) -> (Vec<f64>, Vec<f64>) {
        let mut scratch = crate::model::EvalScratch::default();
        let (mut c, mut b) = (vec![0.0f32; L], vec![0.0f32; L * D]);
        model
            .eval_parts(field.centre_of(v), &mut scratch, &mut c, &mut b)
            .unwrap();
        let value = (0..D)
            .map(|k| {
                (0..L)
                    .map(|l| f64::from(c[l]) * f64::from(b[l * D + k]))
                    .sum()
            })
            .collect();
        (b.iter().map(|&x| f64::from(x)).collect(), value)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(16))]

        /// The normal equations hold at every projected centre: the residual `f̂ − f` is
        /// orthogonal to the local basis up to the ridge, `Bᵀ(f̂ − f) + λc = 0`; the basis and
        /// the voxels outside the mask are untouched.
        #[test]
        fn the_residual_at_each_centre_is_orthogonal_to_the_local_basis(
            seed in 0u64..1000, lambda in prop::sample::select(vec![1e-8f32, 1e-4, 1e-1]),
            mask in prop::collection::vec(prop::bool::weighted(0.7), 60),
        ) {
            let (field, model) = setup(seed);
            let projected = project_on_centres(&field, Some(&mask), model.clone(), lambda).unwrap();
            prop_assert_eq!(projected.basis(), model.basis());
            for v in 0..field.num_voxels() {
                if !mask[v] {
                    prop_assert_eq!(projected.coefficients().row(v), model.coefficients().row(v));
                    continue;
                }
                let (b, value) = at_centre(&projected, &field, v);
                let f = field.voxel(v);
                let scale = f.iter().map(|&x| f64::from(x).abs()).fold(0.0, f64::max).max(1e-30);
                for l in 0..L {
                    let c = f64::from(projected.coefficients()[[v, l]]);
                    let g: f64 = (0..D).map(|k| b[l * D + k] * (value[k] - f64::from(f[k]))).sum::<f64>()
                        + f64::from(lambda) * c;
                    let norm: f64 = (0..D).map(|k| b[l * D + k].powi(2)).sum::<f64>().sqrt();
                    prop_assert!(g.abs() <= 1e-4 * scale * (norm + 1.0), "voxel {v}, l {l}: {g}");
                }
            }
        }

        /// Scaling one voxel's vector scales its projected coefficients alike and leaves every
        /// other voxel's alone (λ → 0): a voxel's centre error is relative to its own magnitude.
        #[test]
        fn a_voxels_coefficients_follow_its_own_vector_only(
            seed in 0u64..1000, voxel in 0usize..60, scale in 1e-4f32..1e2,
        ) {
            let (field, model) = setup(seed);
            let mut scaled = field.clone();
            scaled.voxel_mut(voxel).iter_mut().for_each(|x| *x *= scale);
            let lambda = 1e-12;
            let a = project_on_centres(&field, None, model.clone(), lambda).unwrap();
            let b = project_on_centres(&scaled, None, model, lambda).unwrap();
            for v in 0..field.num_voxels() {
                for l in 0..L {
                    let (x, y) = (a.coefficients()[[v, l]], b.coefficients()[[v, l]]);
                    let want = if v == voxel { x * scale } else { x };
                    prop_assert!((y - want).abs() <= 1e-3 * want.abs().max(1e-6 * scale.max(1.0)), "voxel {v}: {y} vs {want}");
                }
            }
        }
    }

    /// A field that is the model's own value at every centre is reproduced there.
    #[test]
    fn a_field_in_the_local_subspaces_is_reproduced_at_the_centres() {
        let (field, model) = setup(3);
        let mut exact = field.clone();
        for v in 0..field.num_voxels() {
            let (_, value) = at_centre(&model, &field, v);
            for (o, x) in exact.voxel_mut(v).iter_mut().zip(value) {
                *o = x as f32;
            }
        }
        let projected = project_on_centres(&exact, None, model, 1e-12).unwrap();
        for v in 0..field.num_voxels() {
            let (_, value) = at_centre(&projected, &exact, v);
            for (&want, got) in exact.voxel(v).iter().zip(value) {
                assert!((got - f64::from(want)).abs() <= 1e-4 * (1.0 + f64::from(want).abs()));
            }
        }
    }
}
