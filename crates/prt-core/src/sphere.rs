use glam::Vec3;
use ndarray::Array2;

/// A finite linear basis of real functions on the unit sphere: spherical harmonics, sets of
/// spherical Gaussians, the ambient cube, ambient dice (crate `prt-sphere`).
///
/// Encoders (progressive least squares in `prt-plsq`) and projections (the tracer's transfer
/// vectors) are generic over this trait.
///
/// Directions are unit `Vec3` in prt's frame: right-handed, +Y up.
pub trait SphericalBasis: Send + Sync {
    /// Number of basis functions.
    fn len(&self) -> usize;

    /// Whether the basis is empty (never true for the bases prt constructs).
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Evaluates every basis function at unit direction `dir` into `out[..self.len()]`.
    ///
    /// # Panics
    /// If `out.len() < self.len()`.
    fn eval(&self, dir: Vec3, out: &mut [f32]);

    /// The Gram matrix `G_ij = ∫_S² B_i(ω) B_j(ω) dω` (`len × len`, f64), analytic where a closed
    /// form is known and by quadrature otherwise. Symmetric positive definite for a basis of
    /// linearly independent functions; the identity for an orthonormal basis.
    fn gram(&self) -> Array2<f64>;

    /// Whether the basis is orthonormal over the sphere (its Gram matrix is the identity).
    fn is_orthonormal(&self) -> bool {
        false
    }

    /// A short human-readable name ("SH order 3", "SG 12 spiral λ=6", ...).
    fn name(&self) -> String;
}
