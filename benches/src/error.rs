//! The relative error every comparison in the experiments reports.

use prt_core::GridField;

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
}
