use glam::Vec3;

use crate::{CoreError, GridField, Progress};

/// A compressed representation of a vector field that reconstructs `f̂(x)` anywhere in its
/// domain: Moving Basis Decomposition and every PCA-family baseline implement it, so one
/// evaluation harness compares them on equal terms.
pub trait FieldModel: Send + Sync {
    /// Dimension D of the reconstructed vectors.
    fn dim(&self) -> usize;

    /// Reconstructs `f̂(x)` into `out` (`out.len() == self.dim()`).
    fn eval(&self, x: Vec3, out: &mut [f32]) -> Result<(), CoreError>;

    /// Number of scalars the model stores (coefficients, basis vectors, means, ...): the
    /// numerator of bytes-per-voxel before quantisation.
    fn stored_scalars(&self) -> usize;

    /// A short name for tables ("MBD rank 8", "BPCA", ...).
    fn name(&self) -> String;
}

/// Anything that fits a [`FieldModel`] to a [`GridField`].
pub trait Compressor {
    /// The model it produces.
    type Model: FieldModel;
    /// Its error type.
    type Error: std::error::Error + Send + Sync + 'static;

    /// Fits a model to `field`, reporting progress and honouring cancellation.
    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<Self::Model, Self::Error>;
}

/// Evaluates `model` at the voxel centres of a `dims` grid over `field_like`'s box, giving a
/// [`GridField`] that is interpolated trilinearly like the input. The MBD paper resamples every
/// method this way before comparing them, so that all are judged as trilinear volumes.
pub fn resample_to_grid(
    model: &dyn FieldModel,
    dims: [usize; 3],
    bounds: crate::Aabb,
) -> Result<GridField, CoreError> {
    let mut out = GridField::new(dims, bounds, model.dim())?;
    for v in 0..out.num_voxels() {
        let centre = out.centre_of(v);
        model.eval(centre, out.voxel_mut(v))?;
    }
    out.check_finite()?;
    Ok(out)
}
