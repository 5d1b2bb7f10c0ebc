//! A per-voxel weighting of the fit's loss, exact to undo because the transfer is linear and
//! the coefficients sit one per voxel.

use ndarray::Array2;
use prt_core::GridField;

use crate::MbdError;

/// Weights each voxel's term of the loss by the inverse of its own magnitude (beyond the paper,
/// opt-in): the fit sees `w_v f_v` with `w_v = (max(‖f_v‖, floor · m) / m)^−exponent`, `m` the
/// mean of `‖f_v‖` over the fitted voxels, and the fitted coefficients of voxel `v` are divided
/// by `w_v` afterwards, which is exact at every voxel centre (one coefficient hat per voxel
/// centre, 1 there and 0 at every other centre). With exponent 1 every voxel's *relative* error
/// counts alike, so dim interiors are not traded for sunlit voxels; the floor keeps empty or
/// near-black voxels from dominating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossWeighting {
    /// 0 is the paper's loss; 1 evens out relative error.
    pub exponent: f32,
    /// Magnitudes below `floor` × the mean are weighted as if at `floor` × the mean.
    pub floor: f32,
}

impl Default for LossWeighting {
    /// Exponent 1 (relative error), floor 0.05.
    fn default() -> Self {
        Self {
            exponent: 1.0,
            floor: 0.05,
        }
    }
}

impl LossWeighting {
    /// The weight of every voxel of `field` (x fastest), from the voxels `valid` (`None`: all);
    /// invalid voxels get weight 1.
    ///
    /// Errors: [`MbdError::InvalidOption`] for an exponent outside `[0, 4]` or a floor outside
    /// `(0, 1]`; [`MbdError::ShapeMismatch`] for a mask of the wrong length.
    pub fn weights(&self, field: &GridField, valid: Option<&[bool]>) -> Result<Vec<f32>, MbdError> {
        self.validate()?;
        let n = field.num_voxels();
        if let Some(valid) = valid
            && valid.len() != n
        {
            return Err(MbdError::ShapeMismatch {
                what: "validity mask",
                expected: vec![n],
                got: vec![valid.len()],
            });
        }
        let fitted = |v: usize| valid.is_none_or(|m| m[v]);
        let norms: Vec<f64> = (0..n).map(|v| Self::magnitude(field.voxel(v))).collect();
        let (sum, count) = (0..n)
            .filter(|&v| fitted(v))
            .fold((0.0f64, 0usize), |(s, c), v| (s + norms[v], c + 1));
        let mean = if count > 0 { sum / count as f64 } else { 0.0 };
        Ok((0..n)
            .map(|v| {
                if fitted(v) {
                    self.weight(norms[v], mean)
                } else {
                    1.0
                }
            })
            .collect())
    }

    /// The weight of a voxel of magnitude `norm` ([`LossWeighting::magnitude`]) among fitted
    /// voxels of mean magnitude `mean`: what [`LossWeighting::weights`] gives each fitted voxel,
    /// for fits that see the field a piece at a time and learn the mean first. 1 when `mean` is
    /// not positive (an all-zero field).
    pub fn weight(&self, norm: f64, mean: f64) -> f32 {
        if mean <= 0.0 || mean.is_nan() {
            return 1.0;
        }
        let floor = f64::from(self.floor) * mean;
        (norm.max(floor) / mean).powf(-f64::from(self.exponent)) as f32
    }

    /// Reads `none` (the paper's loss: `None`) or `relative[:EXPONENT[,FLOOR]]` (the default's
    /// values for what is left out), as `prt bake --loss-weighting` takes it, and validates it.
    ///
    /// Errors: [`MbdError::InvalidOption`] for any other text or a value out of range.
    pub fn parse(spec: &str) -> Result<Option<LossWeighting>, MbdError> {
        let invalid = |why: String| MbdError::InvalidOption {
            what: "loss weighting",
            why,
        };
        if spec == "none" {
            return Ok(None);
        }
        let values = match spec.strip_prefix("relative") {
            Some("") => None,
            Some(rest) => Some(rest.strip_prefix(':').ok_or_else(|| {
                invalid(format!(
                    "{spec}: expected none or relative[:EXPONENT[,FLOOR]]"
                ))
            })?),
            None => {
                return Err(invalid(format!(
                    "{spec}: expected none or relative[:EXPONENT[,FLOOR]]"
                )));
            }
        };
        let mut weighting = LossWeighting::default();
        if let Some(values) = values {
            let numbers = values
                .split(',')
                .map(|v| v.trim().parse::<f32>())
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| invalid(format!("{spec}: {e}")))?;
            match numbers[..] {
                [exponent] => weighting.exponent = exponent,
                [exponent, floor] => weighting = LossWeighting { exponent, floor },
                _ => {
                    return Err(invalid(format!(
                        "{spec}: expected relative[:EXPONENT[,FLOOR]]"
                    )));
                }
            }
        }
        weighting.validate()?;
        Ok(Some(weighting))
    }

    /// Refuses an exponent outside `[0, 4]` or a floor outside `(0, 1]`
    /// ([`MbdError::InvalidOption`]).
    pub fn validate(&self) -> Result<(), MbdError> {
        if !(0.0..=4.0).contains(&self.exponent) {
            return Err(MbdError::InvalidOption {
                what: "loss weighting exponent",
                why: format!("{} is not in [0, 4]", self.exponent),
            });
        }
        if !(self.floor > 0.0 && self.floor <= 1.0) {
            return Err(MbdError::InvalidOption {
                what: "loss weighting floor",
                why: format!("{} is not in (0, 1]", self.floor),
            });
        }
        Ok(())
    }

    /// A voxel's magnitude `‖f‖`, summed in f64: what the weights are a function of.
    pub fn magnitude(vector: &[f32]) -> f64 {
        vector
            .iter()
            .map(|&x| f64::from(x) * f64::from(x))
            .sum::<f64>()
            .sqrt()
    }
}

/// `field` with each voxel's vector multiplied by its weight.
pub(crate) fn weighted_field(field: &GridField, weights: &[f32]) -> GridField {
    let mut out = field.clone();
    for (v, &w) in weights.iter().enumerate() {
        out.voxel_mut(v).iter_mut().for_each(|x| *x *= w);
    }
    out
}

/// Divides the coefficients of node `v` (one per voxel) by `weights[v]`.
pub(crate) fn unweight_coefficients(
    coefficients: &mut Array2<f32>,
    weights: &[f32],
) -> Result<(), MbdError> {
    if coefficients.nrows() != weights.len() {
        return Err(MbdError::ShapeMismatch {
            what: "coefficient nodes (one per voxel)",
            expected: vec![weights.len()],
            got: vec![coefficients.nrows()],
        });
    }
    for (mut row, &w) in coefficients.rows_mut().into_iter().zip(weights) {
        row.iter_mut().for_each(|c| *c /= w);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_reads_what_prt_bake_takes() {
        assert_eq!(LossWeighting::parse("none").unwrap(), None);
        assert_eq!(
            LossWeighting::parse("relative").unwrap(),
            Some(LossWeighting::default())
        );
        assert_eq!(
            LossWeighting::parse("relative:0.5").unwrap(),
            Some(LossWeighting {
                exponent: 0.5,
                ..LossWeighting::default()
            })
        );
        assert_eq!(
            LossWeighting::parse("relative:2, 0.1").unwrap(),
            Some(LossWeighting {
                exponent: 2.0,
                floor: 0.1
            })
        );
        for bad in [
            "",
            "None",
            "relativ",
            "relative:",
            "relative1",
            "relative:x",
            "relative:1,2,3",
            "relative:5",
            "relative:1,0",
            "relative:NaN",
        ] {
            assert!(
                matches!(
                    LossWeighting::parse(bad),
                    Err(MbdError::InvalidOption { .. })
                ),
                "{bad:?} accepted"
            );
        }
    }
}
