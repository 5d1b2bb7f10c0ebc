//! Texels of an atlas: where each lies on the surface, dilation and seam stitching.

use glam::{Vec2, Vec3};

use crate::Atlas;
use crate::atlas::shared_edges;

/// A texel's sample point on the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Texel {
    /// The triangle it lies on.
    pub triangle: u32,
    /// World-space position.
    pub position: Vec3,
    /// Unit geometric normal (the triangle's winding side).
    pub normal: Vec3,
}

/// Every texel of an atlas that a triangle touches, with its surface point.
#[derive(Debug, Clone, PartialEq)]
pub struct TexelMap {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Row-major, top row first; `None` for texels no triangle touches.
    pub texels: Vec<Option<Texel>>,
    /// Texels whose centre lies inside a triangle.
    pub inside: usize,
    /// Texels a triangle touches without covering their centre (their point is the nearest
    /// point of the triangle, so that bilinear filtering at chart borders reads lit values).
    pub border: usize,
    /// Texels whose centre lies inside two triangles (overlapping lightmap UVs).
    pub overlapping: usize,
}

impl TexelMap {
    /// Places the texels of `atlas` on `triangles` (the triangles the atlas was made for).
    ///
    /// A texel whose centre is inside a triangle takes that point; one that a triangle only
    /// touches (centre within 0.75 texel of it) takes the triangle's nearest point, unless a
    /// centre is inside another triangle. The first triangle wins a texel claimed twice.
    pub fn new(triangles: &[[Vec3; 3]], atlas: &Atlas) -> Self {
        let (w, h) = (atlas.width as usize, atlas.height as usize);
        let mut texels: Vec<Option<Texel>> = vec![None; w * h];
        // Per texel: 1 + min barycentric when the centre is inside, -distance when touched.
        let mut score = vec![f32::NEG_INFINITY; w * h];
        let mut overlapping = 0;
        for (t, (tri, uv)) in triangles.iter().zip(&atlas.uvs).enumerate() {
            let area = (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]);
            if area.abs() < 1e-6 {
                continue;
            }
            let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
            let (lo, hi) = uv.iter().fold(
                (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
                |(lo, hi), &p| (lo.min(p), hi.max(p)),
            );
            let x0 = (lo.x - 1.0).floor().max(0.0) as usize;
            let y0 = (lo.y - 1.0).floor().max(0.0) as usize;
            let x1 = ((hi.x + 1.0).ceil().max(0.0) as usize).min(w);
            let y1 = ((hi.y + 1.0).ceil().max(0.0) as usize).min(h);
            for y in y0..y1 {
                for x in x0..x1 {
                    let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let b = barycentrics(uv, area, c);
                    let inside = b.min_element();
                    let (s, bary) = if inside >= -1e-5 {
                        (1.0 + inside, b)
                    } else {
                        let (d, nb) = nearest_on_triangle(uv, area, c);
                        if d > 0.75 {
                            continue;
                        }
                        (-d, nb)
                    };
                    let i = y * w + x;
                    if s > 1.0 + 1e-3 && score[i] > 1.0 + 1e-3 {
                        overlapping += 1;
                    }
                    if s > score[i] && !(score[i] >= 1.0 && s >= 1.0) {
                        score[i] = s;
                        texels[i] = Some(Texel {
                            triangle: t as u32,
                            position: tri[0] * bary.x + tri[1] * bary.y + tri[2] * bary.z,
                            normal,
                        });
                    }
                }
            }
        }
        let inside = score.iter().filter(|&&s| s >= 1.0).count();
        let border = texels.iter().filter(|t| t.is_some()).count() - inside;
        Self {
            width: atlas.width,
            height: atlas.height,
            texels,
            inside,
            border,
            overlapping,
        }
    }

    /// Number of texels with a surface point.
    pub fn len(&self) -> usize {
        self.inside + self.border
    }

    /// Whether no texel has a surface point.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

fn barycentrics(uv: &[Vec2; 3], area: f32, p: Vec2) -> glam::Vec3 {
    let b1 = (p - uv[0]).perp_dot(uv[2] - uv[0]) / area;
    let b2 = (uv[1] - uv[0]).perp_dot(p - uv[0]) / area;
    glam::Vec3::new(1.0 - b1 - b2, b1, b2)
}

/// Distance from `p` to the triangle and the barycentrics of the nearest point.
fn nearest_on_triangle(uv: &[Vec2; 3], area: f32, p: Vec2) -> (f32, glam::Vec3) {
    let mut best = (f32::INFINITY, glam::Vec3::ZERO);
    for e in 0..3 {
        let (a, b) = (uv[e], uv[(e + 1) % 3]);
        let d = b - a;
        let s = ((p - a).dot(d) / d.length_squared().max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
        let q = a + d * s;
        let dist = (p - q).length();
        if dist < best.0 {
            best = (dist, barycentrics(uv, area, q).max(glam::Vec3::ZERO));
        }
    }
    let sum = best.1.element_sum().max(f32::MIN_POSITIVE);
    (best.0, best.1 / sum)
}

/// Fills empty texels next to filled ones with the mean of their filled 8-neighbours,
/// `rings` times (each ring reads the previous one), so that bilinear filtering and mip levels
/// near chart borders read lit values. `layers` are images of `channels` values per texel;
/// `filled` marks the texels with values and is updated.
pub fn dilate_texels(
    layers: &mut [Vec<f32>],
    channels: usize,
    filled: &mut [bool],
    width: usize,
    rings: usize,
) {
    let height = filled.len() / width.max(1);
    for _ in 0..rings {
        let before = filled.to_vec();
        let mut grown = Vec::new();
        for y in 0..height {
            for x in 0..width {
                if before[y * width + x] {
                    continue;
                }
                let mut sources = Vec::new();
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        if nx < 0 || ny < 0 || nx >= width as i64 || ny >= height as i64 {
                            continue;
                        }
                        let j = ny as usize * width + nx as usize;
                        if before[j] {
                            sources.push(j);
                        }
                    }
                }
                if !sources.is_empty() {
                    grown.push((y * width + x, sources));
                }
            }
        }
        if grown.is_empty() {
            return;
        }
        for (i, sources) in grown {
            for layer in layers.iter_mut() {
                for c in 0..channels {
                    let sum: f32 = sources.iter().map(|&j| layer[j * channels + c]).sum();
                    layer[i * channels + c] = sum / sources.len() as f32;
                }
            }
            filled[i] = true;
        }
    }
}

/// Pairs of texels on the two sides of a UV seam: an edge that two triangles share in space
/// but not in the atlas, on a smooth surface (normals within 10°). Stitching makes each pair
/// agree, so the seam does not show.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Seams {
    /// Texel index pairs (row-major), each pair once.
    pub pairs: Vec<(u32, u32)>,
}

impl Seams {
    /// The seams of `atlas` over `triangles`, sampled every half texel along each seam edge.
    pub fn new(triangles: &[[Vec3; 3]], atlas: &Atlas, map: &TexelMap) -> Self {
        let w = atlas.width as usize;
        let texel_at = |p: Vec2| -> Option<usize> {
            let (x, y) = (p.x.floor(), p.y.floor());
            if x < 0.0 || y < 0.0 || x >= atlas.width as f32 || y >= atlas.height as f32 {
                return None;
            }
            let i = y as usize * w + x as usize;
            map.texels[i].is_some().then_some(i)
        };
        let normal = |t: usize| {
            let tri = triangles[t];
            (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero()
        };
        let mut pairs = Vec::new();
        let mut edges: Vec<_> = shared_edges(triangles)
            .into_values()
            .filter(|l| l.len() == 2)
            .collect();
        edges.sort();
        for list in edges {
            let [(ta, ea), (tb, eb)] = [list[0], list[1]];
            if normal(ta).dot(normal(tb)) < 10f32.to_radians().cos() {
                continue;
            }
            let (a0, a1) = (atlas.uvs[ta][ea], atlas.uvs[ta][(ea + 1) % 3]);
            let (mut b0, mut b1) = (atlas.uvs[tb][eb], atlas.uvs[tb][(eb + 1) % 3]);
            // Orient b like a: match the spatial endpoints.
            if triangles[ta][ea].distance_squared(triangles[tb][eb])
                > triangles[ta][ea].distance_squared(triangles[tb][(eb + 1) % 3])
            {
                std::mem::swap(&mut b0, &mut b1);
            }
            if a0 == b0 && a1 == b1 {
                continue;
            }
            let steps = (2.0 * (a1 - a0).length().max((b1 - b0).length()))
                .ceil()
                .max(1.0) as usize;
            for k in 0..=steps {
                let s = k as f32 / steps as f32;
                if let (Some(i), Some(j)) = (texel_at(a0.lerp(a1, s)), texel_at(b0.lerp(b1, s)))
                    && i != j
                {
                    pairs.push((i.min(j) as u32, i.max(j) as u32));
                }
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        Self { pairs }
    }

    /// Sets both texels of every pair to their mean, in every layer, `iterations` times.
    pub fn stitch(&self, layers: &mut [Vec<f32>], channels: usize, iterations: usize) {
        for _ in 0..iterations {
            for layer in layers.iter_mut() {
                for &(i, j) in &self.pairs {
                    for c in 0..channels {
                        let (a, b) = (i as usize * channels + c, j as usize * channels + c);
                        let mean = 0.5 * (layer[a] + layer[b]);
                        layer[a] = mean;
                        layer[b] = mean;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{UnwrapConfig, unwrap_charts};

    /// Every texel whose centre is inside a triangle gets a point on that triangle.
    #[test]
    fn texels_inside_charts_lie_on_their_triangles() {
        let scene = prt_trace::Scene::cornell_box();
        let tris = scene.triangles();
        let atlas = unwrap_charts(
            tris,
            &UnwrapConfig {
                texels_per_metre: 10.0,
                ..Default::default()
            },
        )
        .unwrap();
        let map = TexelMap::new(tris, &atlas);
        assert_eq!(map.overlapping, 0);
        assert!(map.inside > 0 && map.border > 0);
        for texel in map.texels.iter().flatten() {
            let t = tris[texel.triangle as usize];
            let n = (t[1] - t[0]).cross(t[2] - t[0]);
            assert!(texel.position.is_finite() && texel.normal.is_normalized());
            // On the triangle's plane and inside its bounding box.
            assert!((texel.position - t[0]).dot(n.normalize()).abs() < 1e-4);
            let lo = t[0].min(t[1]).min(t[2]) - Vec3::splat(1e-4);
            let hi = t[0].max(t[1]).max(t[2]) + Vec3::splat(1e-4);
            assert!(texel.position.cmpge(lo).all() && texel.position.cmple(hi).all());
        }
        // The covered area matches the triangles' UV area within the border ring.
        let uv_area: f32 = atlas
            .uvs
            .iter()
            .map(|u| 0.5 * (u[1] - u[0]).perp_dot(u[2] - u[0]).abs())
            .sum();
        assert!(
            (map.inside as f32 - uv_area).abs() < 0.2 * uv_area,
            "{} vs {uv_area}",
            map.inside
        );
    }

    #[test]
    fn overlapping_uvs_are_counted() {
        let tris = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [Vec3::Z, Vec3::Z + Vec3::X, Vec3::Z + Vec3::Y],
        ];
        let uv = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 1.0),
        ];
        let atlas = crate::atlas_from_uvs(&tris, &[uv, uv], 16, 16).unwrap();
        let map = TexelMap::new(&tris, &atlas);
        assert!(map.overlapping > 50, "{}", map.overlapping);
    }

    #[test]
    fn dilation_fills_the_ring_around_filled_texels() {
        let (w, h) = (5, 5);
        let mut filled = vec![false; w * h];
        filled[12] = true;
        let mut layers = vec![vec![0.0f32; w * h]];
        layers[0][12] = 3.0;
        dilate_texels(&mut layers, 1, &mut filled, w, 1);
        assert_eq!(filled.iter().filter(|&&f| f).count(), 9);
        assert!(
            layers[0]
                .iter()
                .enumerate()
                .all(|(i, &v)| v == if filled[i] { 3.0 } else { 0.0 })
        );
    }
}
