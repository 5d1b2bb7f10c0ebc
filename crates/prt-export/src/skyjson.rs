//! Skies given as SH coefficients in a JSON document.

use prt_sphere::Sky;
use serde_json::Value;

use crate::ExportError;

/// A sky from JSON text in one of two shapes:
///
/// * `{"sh": [[r0..r8], [g0..g8], [b0..b8]]}`: nine coefficients per channel;
/// * `{"coefficients_rgb": [[r, g, b], ...9]}`: nine RGB triples, what `prt encode --basis sh:3`
///   prints.
///
/// Coefficients are in prt's SH convention (radiance, order 3). A missing or non-numeric entry
/// is an error naming its place; a value beyond f32's range is a non-finite error naming its
/// channel and index.
pub fn sky_from_json(text: &str) -> Result<Sky, ExportError> {
    let doc: Value = serde_json::from_str(text).map_err(|e| ExportError::SkyJson(e.to_string()))?;
    let number = |v: &Value, place: String| {
        v.as_f64()
            .map(|x| x as f32)
            .ok_or_else(|| ExportError::SkyJson(format!("{place} is not a number")))
    };
    let array = |v: &Value, len: usize, place: String| -> Result<Vec<Value>, ExportError> {
        match v.as_array() {
            Some(a) if a.len() == len => Ok(a.clone()),
            _ => Err(ExportError::SkyJson(format!(
                "{place} must be an array of {len}"
            ))),
        }
    };
    let mut sh = [[0f32; 9]; 3];
    if let Some(rows) = doc.get("sh") {
        for (c, row) in array(rows, 3, "sh".into())?.iter().enumerate() {
            for (j, v) in array(row, 9, format!("sh[{c}]"))?.iter().enumerate() {
                sh[c][j] = number(v, format!("sh[{c}][{j}]"))?;
            }
        }
    } else if let Some(rows) = doc.get("coefficients_rgb") {
        for (j, row) in array(rows, 9, "coefficients_rgb".into())?
            .iter()
            .enumerate()
        {
            for (c, v) in array(row, 3, format!("coefficients_rgb[{j}]"))?
                .iter()
                .enumerate()
            {
                sh[c][j] = number(v, format!("coefficients_rgb[{j}][{c}]"))?;
            }
        }
    } else {
        return Err(ExportError::SkyJson(
            "expected a \"sh\" or \"coefficients_rgb\" key".into(),
        ));
    }
    Ok(Sky::from_coefficients(sh)?)
}
