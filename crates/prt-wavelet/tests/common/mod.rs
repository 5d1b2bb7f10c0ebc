//! Random BRDF-curve edits shared by the curve and image tests.

use std::ops::Range;

use proptest::prelude::*;
use prt_wavelet::brdf::{beckmann_curve, brush_stroke};

/// One edit of a 1-D BRDF curve: a new Beckmann roughness or a brush stroke.
#[derive(Debug, Clone)]
pub enum Edit {
    Roughness(f32),
    Stroke {
        centre: f32,
        radius: f32,
        delta: f32,
    },
}

/// Roughness changes and strokes over 256 bins, stroke heights drawn from `delta`.
pub fn edit(delta: Range<f32>) -> impl Strategy<Value = Edit> {
    prop_oneof![
        (0.03f32..1.5).prop_map(Edit::Roughness),
        (0.0f32..256.0, 1.0f32..60.0, delta).prop_map(|(centre, radius, delta)| {
            Edit::Stroke {
                centre,
                radius,
                delta,
            }
        }),
    ]
}

/// Applies `e` to `curve` in place.
pub fn apply_edit(curve: &mut Vec<f32>, e: &Edit) {
    match *e {
        Edit::Roughness(m) => *curve = beckmann_curve(m, curve.len()).unwrap(),
        Edit::Stroke {
            centre,
            radius,
            delta,
        } => brush_stroke(curve, centre, radius, delta),
    }
}
