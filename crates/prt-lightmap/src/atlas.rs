//! Lightmap UVs: planar charts by normal clustering, packed on shelves, or the scene's own UVs.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use crate::LightmapError;
use crate::pack::pack_shelves;

/// Knobs of [`unwrap_charts`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnwrapConfig {
    /// Texels per scene unit (metre) along a surface.
    pub texels_per_metre: f32,
    /// Largest angle between a triangle's normal and its chart's normal, degrees.
    pub max_chart_angle_deg: f32,
    /// Empty texels between any two charts and between a chart and the atlas's edges (dilation
    /// fills them): 2 keeps bilinear filtering inside a chart's texels and one ring of dilation
    /// (Unity's default lightmap padding); more for mip levels.
    pub padding: u32,
    /// Largest atlas side, texels.
    pub max_side: u32,
    /// Most triangles per chart (the overlap test inside a chart is quadratic in it).
    pub max_chart_triangles: usize,
}

impl Default for UnwrapConfig {
    fn default() -> Self {
        Self {
            texels_per_metre: 16.0,
            max_chart_angle_deg: 30.0,
            padding: 2,
            max_side: 4096,
            max_chart_triangles: 512,
        }
    }
}

/// Where an atlas's UVs came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UvSource {
    /// Generated charts ([`unwrap_charts`]).
    Charts,
    /// The scene's own lightmap UVs (glTF `TEXCOORD_1`, [`atlas_from_uvs`]).
    Texcoord1,
}

/// A lightmap atlas: every triangle's three corners in texel coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Atlas {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Per triangle, its corners in texels (x right, y down; texel `(i, j)` has its centre at
    /// `(i + 0.5, j + 0.5)`).
    pub uvs: Vec<[Vec2; 3]>,
    /// The chart of each triangle.
    pub chart_of: Vec<u32>,
    /// Number of charts.
    pub charts: usize,
    /// Achieved texels per metre: `sqrt(UV area / surface area)`.
    pub texel_density: f32,
    /// Fraction of the atlas covered by triangles.
    pub packing_efficiency: f32,
    /// Where the UVs came from.
    pub source: UvSource,
    /// Problems found in given UVs (degenerate or out-of-range triangles); overlaps are counted
    /// when texels are placed ([`crate::TexelMap::overlapping`]).
    pub warnings: Vec<String>,
}

impl Atlas {
    /// The UVs as glTF `TEXCOORD_1` values (0..1, origin top-left).
    pub fn normalized_uvs(&self) -> Vec<[Vec2; 3]> {
        let size = Vec2::new(self.width as f32, self.height as f32);
        self.uvs.iter().map(|t| t.map(|p| p / size)).collect()
    }
}

fn triangle_area_2d(t: &[Vec2; 3]) -> f32 {
    0.5 * (t[1] - t[0]).perp_dot(t[2] - t[0])
}

fn check_triangles(triangles: &[[Vec3; 3]]) -> Result<(), LightmapError> {
    if triangles.is_empty() {
        return Err(LightmapError::EmptyScene);
    }
    match triangles
        .iter()
        .position(|t| !t.iter().all(|v| v.is_finite()))
    {
        Some(index) => Err(LightmapError::NonFinite {
            what: "triangle position",
            index,
        }),
        None => Ok(()),
    }
}

fn bounds(points: impl IntoIterator<Item = Vec2>) -> (Vec2, Vec2) {
    points.into_iter().fold(
        (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    )
}

/// The rotation `(cos, sin)` that gives `points` their smallest axis-aligned bounding box: the
/// smallest rectangle around a convex hull has a side on one of its edges (Freeman and Shapira
/// 1975), so each hull edge is tried; the first of equal areas wins.
fn smallest_box_rotation(points: &[Vec2]) -> (f32, f32) {
    let hull = convex_hull(points);
    let mut best = (f32::INFINITY, 1.0, 0.0);
    for i in 0..hull.len() {
        let d = hull[(i + 1) % hull.len()] - hull[i];
        let len = d.length();
        if len <= 0.0 {
            continue;
        }
        // Turning by -atan2(d) lays the edge along +x.
        let (cos, sin) = (d.x / len, -d.y / len);
        let (lo, hi) = bounds(
            hull.iter()
                .map(|p| Vec2::new(cos * p.x - sin * p.y, sin * p.x + cos * p.y)),
        );
        let area = (hi.x - lo.x) * (hi.y - lo.y);
        if area < best.0 * (1.0 - 1e-5) {
            best = (area, cos, sin);
        }
    }
    (best.1, best.2)
}

/// Andrew's monotone chain: the convex hull, counter-clockwise, without collinear points.
fn convex_hull(points: &[Vec2]) -> Vec<Vec2> {
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    sorted.dedup();
    if sorted.len() < 3 {
        return sorted;
    }
    let mut hull: Vec<Vec2> = Vec::with_capacity(2 * sorted.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Vec2>> = if pass == 0 {
            Box::new(sorted.iter())
        } else {
            Box::new(sorted.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && (hull[hull.len() - 1] - hull[hull.len() - 2]).perp_dot(p - hull[hull.len() - 2])
                    <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Whether two triangles (counter-clockwise or not) overlap by more than `eps` (touching
/// along an edge or at a corner is not an overlap): the separating-axis test on their six
/// edge normals.
fn triangles_overlap(a: &[Vec2; 3], b: &[Vec2; 3], eps: f32) -> bool {
    for tri in [a, b] {
        for e in 0..3 {
            let d = tri[(e + 1) % 3] - tri[e];
            let axis = Vec2::new(-d.y, d.x);
            let range = |t: &[Vec2; 3]| {
                t.iter()
                    .map(|p| p.dot(axis))
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
                        (lo.min(v), hi.max(v))
                    })
            };
            let (lo_a, hi_a) = range(a);
            let (lo_b, hi_b) = range(b);
            let tol = eps * axis.length();
            if hi_a <= lo_b + tol || hi_b <= lo_a + tol {
                return false;
            }
        }
    }
    true
}

/// Planar charts by normal clustering, packed on shelves (a Rust-native unwrapper: no C++ build
/// and the same atlas on every platform).
///
/// Triangles are welded by position (1e-6 of the scene's extent) to find shared edges. Seeds
/// are taken largest first; a chart grows over shared edges to triangles whose normal lies
/// within `max_chart_angle_deg` of the seed's and whose projection onto the seed's plane
/// overlaps no triangle already in the chart, up to `max_chart_triangles`. Each chart is
/// projected at `texels_per_metre`, turned to its smallest bounding rectangle lying wider than
/// tall, and packed `padding` texels apart ([`pack_shelves`](crate::pack_shelves)). Charts never overlap and a triangle never overlaps
/// another of its chart.
///
/// Errors: no triangles, a non-finite position, knobs out of range, an atlas over `max_side`.
pub fn unwrap_charts(
    triangles: &[[Vec3; 3]],
    config: &UnwrapConfig,
) -> Result<Atlas, LightmapError> {
    check_triangles(triangles)?;
    let density = config.texels_per_metre;
    if !(density.is_finite() && density > 0.0) {
        return Err(LightmapError::invalid(
            "texels per metre",
            format!("{density} must be > 0"),
        ));
    }
    if !(config.max_chart_angle_deg.is_finite()
        && (0.0..90.0).contains(&config.max_chart_angle_deg))
    {
        return Err(LightmapError::invalid(
            "chart angle",
            format!("{} must be in [0, 90) degrees", config.max_chart_angle_deg),
        ));
    }
    if config.max_chart_triangles == 0 {
        return Err(LightmapError::invalid(
            "triangles per chart",
            "must be at least 1",
        ));
    }
    let normals: Vec<Vec3> = triangles
        .iter()
        .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero())
        .collect();
    let areas: Vec<f32> = triangles
        .iter()
        .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
        .collect();
    let neighbours = edge_neighbours(triangles);
    let cos_max = config.max_chart_angle_deg.to_radians().cos();
    let mut seeds: Vec<usize> = (0..triangles.len()).collect();
    seeds.sort_by(|&a, &b| areas[b].total_cmp(&areas[a]).then(a.cmp(&b)));
    let mut chart_of = vec![u32::MAX; triangles.len()];
    let mut uvs = vec![[Vec2::ZERO; 3]; triangles.len()];
    let mut charts: Vec<Vec<usize>> = Vec::new();
    for seed in seeds {
        if chart_of[seed] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let n = if normals[seed] == Vec3::ZERO {
            Vec3::Y
        } else {
            normals[seed]
        };
        let (u_axis, v_axis) = n.any_orthonormal_pair();
        let project =
            |t: usize| triangles[t].map(|p| Vec2::new(p.dot(u_axis), p.dot(v_axis)) * density);
        let mut members = vec![seed];
        chart_of[seed] = id;
        uvs[seed] = project(seed);
        let mut frontier = 0;
        while frontier < members.len() && members.len() < config.max_chart_triangles {
            let t = members[frontier];
            frontier += 1;
            for &nb in &neighbours[t] {
                if chart_of[nb] != u32::MAX
                    || normals[nb].dot(n) < cos_max
                    || members.len() >= config.max_chart_triangles
                {
                    continue;
                }
                let candidate = project(nb);
                if members
                    .iter()
                    .any(|&m| triangles_overlap(&uvs[m], &candidate, 1e-3))
                {
                    continue;
                }
                chart_of[nb] = id;
                uvs[nb] = candidate;
                members.push(nb);
            }
        }
        charts.push(members);
    }
    // Each chart turned to its smallest bounding rectangle, lying (wider than tall): less
    // empty box around slanted charts, and lower shelves.
    for members in &charts {
        let points: Vec<Vec2> = members.iter().flat_map(|&t| uvs[t]).collect();
        let (cos, sin) = smallest_box_rotation(&points);
        let turn = |p: Vec2| Vec2::new(cos * p.x - sin * p.y, sin * p.x + cos * p.y);
        let (lo, hi) = bounds(points.iter().map(|&p| turn(p)));
        let lying = hi.x - lo.x >= hi.y - lo.y;
        for &t in members {
            uvs[t] = uvs[t].map(|p| {
                let q = turn(p);
                if lying { q } else { Vec2::new(-q.y, q.x) }
            });
        }
    }
    // Chart rectangles: the texels a chart can claim (centres within 0.75 texel of it, see
    // `TexelMap`). With its corner 0.3 texel into the rectangle, a chart `e` texels wide
    // claims none left of it and `floor(e + 0.55)` beyond its first texel.
    const INSET: f32 = 0.3;
    let mut mins = Vec::with_capacity(charts.len());
    let mut sizes = Vec::with_capacity(charts.len());
    for members in &charts {
        let (lo, hi) = bounds(members.iter().flat_map(|&t| uvs[t]));
        mins.push(lo);
        let extent = hi - lo;
        sizes.push([
            ((extent.x + 0.25 + INSET).floor() as u32).saturating_add(1),
            ((extent.y + 0.25 + INSET).floor() as u32).saturating_add(1),
        ]);
    }
    let packing = pack_shelves(&sizes, config.padding, config.max_side)?;
    for (c, members) in charts.iter().enumerate() {
        let origin = Vec2::new(packing.origins[c][0] as f32, packing.origins[c][1] as f32)
            + Vec2::splat(INSET);
        for &t in members {
            uvs[t] = uvs[t].map(|p| p - mins[c] + origin);
        }
    }
    Ok(finish(
        triangles,
        uvs,
        chart_of,
        charts.len(),
        packing.width,
        packing.height,
        UvSource::Charts,
        Vec::new(),
    ))
}

/// An atlas from the scene's own lightmap UVs (glTF `TEXCOORD_1`, 0..1 with the origin
/// top-left, one triple per triangle) at `width × height` texels.
///
/// Degenerate UV triangles (a UV area under 1e-6 texels² for a triangle of positive area) and
/// corners outside 0..1 are reported in [`Atlas::warnings`]; overlaps show when texels are
/// placed ([`crate::TexelMap::overlapping`]). Charts are the connected groups of triangles that
/// share UV corners.
///
/// Errors: no triangles, a length mismatch, a non-finite UV, a zero size.
pub fn atlas_from_uvs(
    triangles: &[[Vec3; 3]],
    uvs: &[[Vec2; 3]],
    width: u32,
    height: u32,
) -> Result<Atlas, LightmapError> {
    check_triangles(triangles)?;
    if uvs.len() != triangles.len() {
        return Err(LightmapError::invalid(
            "lightmap UVs",
            format!(
                "{} UV triangles for {} triangles",
                uvs.len(),
                triangles.len()
            ),
        ));
    }
    if width == 0 || height == 0 {
        return Err(LightmapError::invalid(
            "atlas size",
            format!("{width}×{height}"),
        ));
    }
    if let Some(index) = uvs.iter().position(|t| !t.iter().all(|p| p.is_finite())) {
        return Err(LightmapError::NonFinite {
            what: "lightmap UV",
            index,
        });
    }
    let size = Vec2::new(width as f32, height as f32);
    let texel_uvs: Vec<[Vec2; 3]> = uvs.iter().map(|t| t.map(|p| p * size)).collect();
    let mut warnings = Vec::new();
    let degenerate: Vec<usize> = texel_uvs
        .iter()
        .enumerate()
        .filter(|(_, t)| triangle_area_2d(t).abs() < 1e-6)
        .map(|(i, _)| i)
        .collect();
    if let Some(first) = degenerate.first() {
        warnings.push(format!(
            "{} triangle(s) have degenerate lightmap UVs (first: triangle {first}); they get no texels",
            degenerate.len()
        ));
    }
    let outside = uvs
        .iter()
        .filter(|t| {
            t.iter()
                .any(|p| p.x < 0.0 || p.x > 1.0 || p.y < 0.0 || p.y > 1.0)
        })
        .count();
    if outside > 0 {
        warnings.push(format!(
            "{outside} triangle(s) have lightmap UVs outside 0..1; their texels outside the atlas are dropped"
        ));
    }
    // Charts: triangles connected through identical UV corners.
    let mut parent: Vec<usize> = (0..uvs.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut corner: HashMap<[u32; 2], usize> = HashMap::new();
    for (t, tri) in uvs.iter().enumerate() {
        for p in tri {
            let key = [p.x.to_bits(), p.y.to_bits()];
            let other = *corner.entry(key).or_insert(t);
            let (a, b) = (root(&mut parent, t), root(&mut parent, other));
            parent[a.max(b)] = a.min(b);
        }
    }
    let mut ids: HashMap<usize, u32> = HashMap::new();
    let mut chart_of = Vec::with_capacity(uvs.len());
    for t in 0..uvs.len() {
        let r = root(&mut parent, t);
        let next = ids.len() as u32;
        chart_of.push(*ids.entry(r).or_insert(next));
    }
    let charts = ids.len();
    Ok(finish(
        triangles,
        texel_uvs,
        chart_of,
        charts,
        width,
        height,
        UvSource::Texcoord1,
        warnings,
    ))
}

#[allow(clippy::too_many_arguments)]
fn finish(
    triangles: &[[Vec3; 3]],
    uvs: Vec<[Vec2; 3]>,
    chart_of: Vec<u32>,
    charts: usize,
    width: u32,
    height: u32,
    source: UvSource,
    warnings: Vec<String>,
) -> Atlas {
    let uv_area: f64 = uvs
        .iter()
        .map(|t| f64::from(triangle_area_2d(t).abs()))
        .sum();
    let surface: f64 = triangles
        .iter()
        .map(|t| f64::from(0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()))
        .sum();
    Atlas {
        width,
        height,
        uvs,
        chart_of,
        charts,
        texel_density: if surface > 0.0 {
            (uv_area / surface).sqrt() as f32
        } else {
            0.0
        },
        packing_efficiency: (uv_area / (f64::from(width) * f64::from(height))) as f32,
        source,
        warnings,
    }
}

/// For each triangle, the triangles sharing one of its edges (positions welded at 1e-6 of the
/// scene's extent).
fn edge_neighbours(triangles: &[[Vec3; 3]]) -> Vec<Vec<usize>> {
    let edges = shared_edges(triangles);
    let mut out = vec![Vec::new(); triangles.len()];
    for list in edges.values() {
        for &(a, _) in list {
            for &(b, _) in list {
                if a != b && !out[a].contains(&b) {
                    out[a].push(b);
                }
            }
        }
    }
    for list in &mut out {
        list.sort_unstable();
    }
    out
}

/// Triangles (and the index of the edge inside each) per welded edge.
pub(crate) fn shared_edges(triangles: &[[Vec3; 3]]) -> HashMap<[[i64; 3]; 2], Vec<(usize, usize)>> {
    let (lo, hi) = triangles.iter().flatten().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let step = ((hi - lo).max_element() * 1e-6).max(f32::MIN_POSITIVE);
    let key = |p: Vec3| ((p - lo) / step).round().as_i64vec3().to_array();
    let mut edges: HashMap<[[i64; 3]; 2], Vec<(usize, usize)>> = HashMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (key(tri[e]), key(tri[(e + 1) % 3]));
            edges.entry([a.min(b), a.max(b)]).or_default().push((t, e));
        }
    }
    edges
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn the_cornell_box_unwraps_into_non_overlapping_charts() {
        let scene = prt_trace::Scene::cornell_box();
        let atlas = unwrap_charts(scene.triangles(), &UnwrapConfig::default()).unwrap();
        // One chart per flat face: 5 walls, the light, 5 faces per box.
        assert_eq!(atlas.charts, 16);
        assert!(
            (atlas.texel_density - 16.0).abs() < 0.01,
            "density {}",
            atlas.texel_density
        );
        assert!(
            atlas.packing_efficiency > 0.4,
            "efficiency {}",
            atlas.packing_efficiency
        );
        for (i, a) in atlas.uvs.iter().enumerate() {
            for (j, b) in atlas.uvs.iter().enumerate().skip(i + 1) {
                assert!(
                    !triangles_overlap(a, b, 1e-3),
                    "triangles {i} and {j} overlap"
                );
            }
            assert!(triangle_area_2d(a) > 0.0, "triangle {i} flipped");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Random triangle soups unwrap without overlaps, inside the atlas, and the texels of
        /// different charts (and the atlas's edges) stay `padding` texels apart.
        #[test]
        fn unwrapped_triangles_never_overlap(
            points in proptest::collection::vec((-2f32..2.0, -2f32..2.0, -2f32..2.0), 3..60),
            texels_per_metre in 1f32..12.0,
            padding in 0u32..4,
        ) {
            let triangles: Vec<[Vec3; 3]> = points
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]].map(|(x, y, z)| Vec3::new(x, y, z)))
                .filter(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() > 1e-3)
                .collect();
            prop_assume!(!triangles.is_empty());
            let config = UnwrapConfig { texels_per_metre, padding, ..Default::default() };
            let atlas = unwrap_charts(&triangles, &config).unwrap();
            for (i, a) in atlas.uvs.iter().enumerate() {
                for p in a {
                    prop_assert!(p.x >= 0.0 && p.y >= 0.0 && p.x <= atlas.width as f32 && p.y <= atlas.height as f32);
                }
                for b in atlas.uvs.iter().skip(i + 1) {
                    prop_assert!(!triangles_overlap(a, b, 1e-3));
                }
            }
            // Every texel a chart claims (see `TexelMap`), against every other chart's within
            // `padding` texels, and the edges.
            let map = crate::TexelMap::new(&triangles, &atlas);
            let (w, h, pad) = (atlas.width as i64, atlas.height as i64, i64::from(padding));
            let chart = |x: i64, y: i64| map.texels[(y * w + x) as usize]
                .map(|t| atlas.chart_of[t.triangle as usize]);
            prop_assert!(!map.is_empty());
            for y in 0..h {
                for x in 0..w {
                    let Some(c) = chart(x, y) else { continue };
                    prop_assert!(
                        x >= pad && y >= pad && x < w - pad && y < h - pad,
                        "texel ({}, {}) within {} of the edge of {}×{}", x, y, pad, w, h
                    );
                    for ny in (y - pad).max(0)..=(y + pad).min(h - 1) {
                        for nx in (x - pad).max(0)..=(x + pad).min(w - 1) {
                            let other = chart(nx, ny);
                            prop_assert!(
                                other.is_none_or(|o| o == c),
                                "charts {} and {:?} at ({}, {}) and ({}, {})", c, other, x, y, nx, ny
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn given_uvs_report_degenerate_triangles() {
        let tris = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [Vec3::X, Vec3::X + Vec3::Y, Vec3::Y],
        ];
        let uvs = [
            [
                Vec2::new(0.0, 0.0),
                Vec2::new(1.0, 0.0),
                Vec2::new(0.0, 1.0),
            ],
            [Vec2::new(0.5, 0.5); 3],
        ];
        let atlas = atlas_from_uvs(&tris, &uvs, 8, 8).unwrap();
        assert_eq!(atlas.source, UvSource::Texcoord1);
        assert!(
            atlas.warnings.iter().any(|w| w.contains("degenerate")),
            "{:?}",
            atlas.warnings
        );
        let bad = [uvs[0], [Vec2::new(f32::NAN, 0.0); 3]];
        assert_eq!(
            atlas_from_uvs(&tris, &bad, 8, 8),
            Err(LightmapError::NonFinite {
                what: "lightmap UV",
                index: 1
            })
        );
    }
}
