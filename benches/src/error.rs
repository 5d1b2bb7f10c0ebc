//! The relative error every comparison in the experiments reports.

use prt_core::{CoreError, FieldModel, GridField};

/// `Σ‖approx − reference‖² / Σ‖reference‖²`, accumulated in f64 over any number of value slices.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RelativeError {
    error: f64,
    energy: f64,
}

impl RelativeError {
    /// Adds the squared difference of `approx` and `reference` (same length) and the squared
    /// norm of `reference`.
    pub fn add(&mut self, approx: &[f32], reference: &[f32]) {
        debug_assert_eq!(approx.len(), reference.len());
        for (&a, &r) in approx.iter().zip(reference) {
            self.error += (f64::from(a) - f64::from(r)).powi(2);
            self.energy += f64::from(r).powi(2);
        }
    }

    /// Both sums of `self` and `other` (for parallel reductions).
    pub fn merged(self, other: Self) -> Self {
        Self {
            error: self.error + other.error,
            energy: self.energy + other.energy,
        }
    }

    /// The relative mean squared error (0 when the reference is all zero and so is the error).
    pub fn relative_mse(&self) -> f64 {
        self.error / self.energy.max(f64::MIN_POSITIVE)
    }

    /// The relative RMS error: the square root of [`relative_mse`](Self::relative_mse).
    pub fn relative_rms(&self) -> f64 {
        self.relative_mse().sqrt()
    }
}

/// `‖approx − reference‖ / ‖reference‖` of two slices of the same length (an image, a volume): the
/// relative RMS error of [`RelativeError`] in one call.
pub fn relative_rms(approx: &[f32], reference: &[f32]) -> f64 {
    let mut sum = RelativeError::default();
    sum.add(approx, reference);
    sum.relative_rms()
}

/// The relative MSE of `value(v, out)` against `reference` at the centres of the voxels `valid`
/// marks (the error a bake's model makes where the volume is meaningful).
pub fn relative_mse_at_centres(
    reference: &GridField,
    valid: &[bool],
    mut value: impl FnMut(usize, &mut [f32]),
) -> f64 {
    let mut out = vec![0.0f32; reference.dim()];
    let mut sum = RelativeError::default();
    for v in (0..reference.num_voxels()).filter(|&v| valid[v]) {
        value(v, &mut out);
        sum.add(&out, reference.voxel(v));
    }
    sum.relative_mse()
}

/// The relative MSE of `model` against `reference` at the centres of the voxels `valid` marks:
/// a container's error as written, where the volume is meaningful; the first evaluation error
/// if any.
pub fn model_error_at_centres(
    model: &(impl FieldModel + ?Sized),
    reference: &GridField,
    valid: &[bool],
) -> Result<f64, CoreError> {
    let mut failed = None;
    let error = relative_mse_at_centres(reference, valid, |v, out| {
        if let Err(e) = model.eval(reference.centre_of(v), out) {
            failed.get_or_insert(e);
        }
    });
    failed.map_or(Ok(error), Err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_error_of_a_scaled_reference() {
        let mut sum = RelativeError::default();
        sum.add(&[1.5, 3.0], &[1.0, 2.0]);
        assert_eq!(sum.relative_mse(), 0.25);
        assert_eq!(sum.relative_rms(), 0.5);
        assert_eq!(RelativeError::default().relative_mse(), 0.0);
    }

    /// The reference's trilinear samples times a factor.
    struct Scaled<'a>(&'a GridField, f32);

    impl FieldModel for Scaled<'_> {
        fn dim(&self) -> usize {
            self.0.dim()
        }

        fn eval(&self, x: prt_core::glam::Vec3, out: &mut [f32]) -> Result<(), CoreError> {
            self.0.sample(x, out)?;
            out.iter_mut().for_each(|o| *o *= self.1);
            Ok(())
        }

        fn stored_scalars(&self) -> usize {
            0
        }

        fn name(&self) -> String {
            "scaled".into()
        }
    }

    #[test]
    fn model_error_counts_only_valid_voxels() {
        let mut reference =
            GridField::new([2, 1, 1], prt_core::Aabb::UNIT, 2).expect("a small field");
        reference.voxel_mut(0).copy_from_slice(&[1.0, 2.0]);
        reference.voxel_mut(1).copy_from_slice(&[5.0, -3.0]);
        let error = model_error_at_centres(&Scaled(&reference, 1.5), &reference, &[true, false]);
        assert!((error.expect("evaluates") - 0.25).abs() < 1e-12);
    }
}
