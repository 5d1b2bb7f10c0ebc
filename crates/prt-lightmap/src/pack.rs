//! Shelf packing of chart rectangles into an atlas.

use crate::LightmapError;

/// Where each rectangle went and the atlas size.
#[derive(Debug, Clone, PartialEq)]
pub struct Packing {
    /// Atlas width in texels.
    pub width: u32,
    /// Atlas height in texels.
    pub height: u32,
    /// Top-left corner of each rectangle, in input order.
    pub origins: Vec<[u32; 2]>,
}

/// Packs `sizes` (width, height in texels) on shelves, `gap` empty texels between any two
/// rectangles and between a rectangle and the atlas's edges (neighbours share their gap):
/// tallest first, left to right, a new shelf when a row is full. Tries widths from the square
/// root of the total area upwards and keeps the smallest atlas; every side stays a multiple of 4
/// (block-compressed formats) and at most `max_side`.
///
/// Errors: an empty rectangle, or no width up to `max_side` that fits
/// ([`LightmapError::AtlasTooLarge`]).
pub fn pack_shelves(sizes: &[[u32; 2]], gap: u32, max_side: u32) -> Result<Packing, LightmapError> {
    if let Some(i) = sizes.iter().position(|s| s[0] == 0 || s[1] == 0) {
        return Err(LightmapError::invalid(
            "chart rectangle",
            format!("rectangle {i} is empty"),
        ));
    }
    // Each rectangle carries the gap on its right and bottom; the atlas adds it on the left
    // and top.
    let sizes: Vec<[u32; 2]> = sizes
        .iter()
        .map(|s| [s[0].saturating_add(gap), s[1].saturating_add(gap)])
        .collect();
    let max_inner = max_side.saturating_sub(gap);
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| (sizes[b][1], sizes[b][0], a).cmp(&(sizes[a][1], sizes[a][0], b)));
    let area: u64 = sizes
        .iter()
        .map(|s| u64::from(s[0]) * u64::from(s[1]))
        .sum();
    let widest = sizes.iter().map(|s| s[0]).max().unwrap_or(1);
    let round4 = |x: u64| x.div_ceil(4) * 4;
    let gap64 = u64::from(gap);
    let mut width =
        round4((area as f64).sqrt().ceil() as u64 + gap64).max(round4(u64::from(widest) + gap64));
    let mut best: Option<(u64, Packing)> = None;
    for _ in 0..24 {
        if width > u64::from(max_side) {
            break;
        }
        let (mut origins, height) = place(&sizes, &order, (width - gap64) as u32);
        for o in &mut origins {
            *o = [o[0] + gap, o[1] + gap];
        }
        let height = round4(u64::from(height) + gap64).max(4);
        if height <= u64::from(max_side) {
            let cost = width * height;
            if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                best = Some((
                    cost,
                    Packing {
                        width: width as u32,
                        height: height as u32,
                        origins,
                    },
                ));
            }
            if height <= width {
                break;
            }
        }
        width = round4(width + width.div_ceil(8));
    }
    match best {
        Some((_, packing)) => Ok(packing),
        None => {
            let (_, height) = place(&sizes, &order, max_inner.max(widest));
            Err(LightmapError::AtlasTooLarge {
                width: max_inner.max(widest) + gap,
                height: height + gap,
                max: max_side,
            })
        }
    }
}

/// Next-fit shelves of `width`: origins in input order and the height used.
fn place(sizes: &[[u32; 2]], order: &[usize], width: u32) -> (Vec<[u32; 2]>, u32) {
    let mut origins = vec![[0u32; 2]; sizes.len()];
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    for &i in order {
        let [w, h] = sizes[i];
        if x + w > width && x > 0 {
            y += shelf;
            x = 0;
            shelf = 0;
        }
        origins[i] = [x, y];
        x += w;
        shelf = shelf.max(h);
    }
    (origins, y + shelf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Packed rectangles lie inside the atlas and never overlap.
        #[test]
        fn packing_keeps_the_gap(
            sizes in proptest::collection::vec((1u32..40, 1u32..40), 1..60),
            gap in 0u32..4,
        ) {
            let sizes: Vec<[u32; 2]> = sizes.into_iter().map(|(w, h)| [w, h]).collect();
            let p = pack_shelves(&sizes, gap, 4096).unwrap();
            prop_assert!(p.width.is_multiple_of(4) && p.height.is_multiple_of(4));
            for (i, (o, s)) in p.origins.iter().zip(&sizes).enumerate() {
                prop_assert!(o[0] >= gap && o[1] >= gap, "rect {} too near the top left", i);
                prop_assert!(
                    o[0] + s[0] + gap <= p.width && o[1] + s[1] + gap <= p.height,
                    "rect {} outside", i
                );
                for (j, (q, t)) in p.origins.iter().zip(&sizes).enumerate().skip(i + 1) {
                    let apart = o[0] + s[0] + gap <= q[0] || q[0] + t[0] + gap <= o[0]
                        || o[1] + s[1] + gap <= q[1] || q[1] + t[1] + gap <= o[1];
                    prop_assert!(apart, "rects {} and {} closer than the gap", i, j);
                }
            }
            let area: u32 = sizes.iter().map(|s| s[0] * s[1]).sum();
            prop_assert!(area <= p.width * p.height);
        }
    }

    #[test]
    fn too_large_a_chart_is_a_typed_error() {
        assert!(matches!(
            pack_shelves(&[[100, 10]], 2, 64),
            Err(LightmapError::AtlasTooLarge { max: 64, .. })
        ));
        assert!(pack_shelves(&[[0, 3]], 2, 64).is_err());
        assert!(pack_shelves(&[[62, 3]], 2, 64).is_err());
        assert!(pack_shelves(&[[60, 3]], 2, 64).is_ok());
    }
}
