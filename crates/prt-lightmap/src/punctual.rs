//! The sun and punctual lights seen directly from texels: deltas in direction, which no
//! hemisphere sample finds, so each texel adds them to its fit in closed form.
//!
//! A delta `E⊥ δ(ω − ω_l)` has the least-squares coefficients `c = E⊥ G⁻¹ B(ω_l)` (`G` the Gram
//! matrix of the measure the samples fit over: the sphere under the hemisphere rule or for the
//! naive projection, the upper hemisphere otherwise), which the fit of the path-traced samples
//! simply gains, since least squares is linear. Non-negative encoders take the non-negative
//! least-squares coefficients of the delta instead (the sum of two non-negative fits stays
//! non-negative). The irradiance basis adds `E⊥ cos θ` exactly.

use glam::Vec3;
use ndarray::{Array1, Array2};
use prt_core::SphericalBasis;

use crate::basis::for_each_hemisphere_cell;
use crate::trace::{Transport, tangent_frame};
use crate::{Encoder, LightmapError};

/// What a texel adds for the sun and the punctual lights it sees.
pub(crate) struct PunctualDirect<'a> {
    transport: &'a Transport<'a>,
    /// `None` for the irradiance basis.
    fit: Option<DeltaFit<'a>>,
}

struct DeltaFit<'a> {
    basis: &'a dyn SphericalBasis,
    gram: Array2<f64>,
    /// `G⁻¹` for unconstrained encoders; `None` for non-negative ones (NNLS per delta).
    gram_inverse: Option<Array2<f64>>,
}

impl<'a> PunctualDirect<'a> {
    /// `None` without a sun or punctual light.
    pub fn new(
        transport: &'a Transport<'a>,
        basis: Option<&'a dyn SphericalBasis>,
        encoder: Encoder,
        hemisphere_rule: bool,
    ) -> Result<Option<Self>, LightmapError> {
        if !transport.has_delta_lights() {
            return Ok(None);
        }
        let fit = match basis {
            None => None,
            Some(basis) => {
                let gram = if hemisphere_rule || encoder == Encoder::Naive {
                    basis.gram()
                } else {
                    hemisphere_gram(basis)
                };
                let gram_inverse = match encoder {
                    Encoder::PlsqNonNegative | Encoder::Nnls => None,
                    _ => Some(
                        prt_linalg::cholesky_solve(
                            gram.view(),
                            Array2::eye(gram.nrows()).view(),
                            1e-12 * gram.diag().sum() / gram.nrows() as f64,
                        )
                        .map_err(|e| {
                            LightmapError::invalid("basis", format!("singular Gram matrix: {e}"))
                        })?,
                    ),
                };
                Some(DeltaFit {
                    basis,
                    gram,
                    gram_inverse,
                })
            }
        };
        Ok(Some(Self { transport, fit }))
    }

    /// Adds the sun and punctual lights seen from `position` (unit `normal`) to the texel's
    /// coefficients (`k × 3`, in the tangent frame of [`tangent_frame`]) and irradiance.
    pub fn add(
        &self,
        position: Vec3,
        normal: Vec3,
        cosine: &[f32],
        coefficients: &mut [f32],
        irradiance: &mut [f32; 3],
    ) -> Result<(), LightmapError> {
        let (tangent, bitangent) = tangent_frame(normal);
        let mut result = Ok(());
        let mut values = Vec::new();
        self.transport
            .texel_deltas(position, normal, |towards, arriving| {
                let Some(fit) = &self.fit else {
                    let e = arriving * normal.dot(towards);
                    for (o, v) in irradiance.iter_mut().zip(e.to_array()) {
                        *o += v;
                    }
                    return;
                };
                let local = Vec3::new(
                    towards.dot(tangent),
                    towards.dot(normal),
                    towards.dot(bitangent),
                )
                .normalize();
                values.resize(fit.basis.len(), 0.0);
                fit.basis.eval(local, &mut values);
                let b = Array1::from_iter(values.iter().map(|&v| f64::from(v)));
                let c = match &fit.gram_inverse {
                    Some(inv) => inv.dot(&b),
                    None => match prt_linalg::nnls_gram(fit.gram.view(), b.view()) {
                        Ok(s) => s.x,
                        Err(e) => {
                            result = Err(LightmapError::invalid(
                                "punctual light projection",
                                e.to_string(),
                            ));
                            return;
                        }
                    },
                };
                let rgb = arriving.to_array();
                for (i, &ci) in c.iter().enumerate() {
                    for ch in 0..3 {
                        let v = (ci * f64::from(rgb[ch])) as f32;
                        coefficients[3 * i + ch] += v;
                        irradiance[ch] += cosine[i] * v;
                    }
                }
            });
        result
    }
}

/// `∫_{ω_y > 0} B_i B_j dω`, by the midpoint rule of `cosine_weights`.
fn hemisphere_gram(basis: &dyn SphericalBasis) -> Array2<f64> {
    let k = basis.len();
    let mut g = Array2::<f64>::zeros((k, k));
    for_each_hemisphere_cell(basis, |_, b, cell| {
        for i in 0..k {
            for j in 0..k {
                g[[i, j]] += f64::from(b[i]) * f64::from(b[j]) * cell;
            }
        }
    });
    g
}
