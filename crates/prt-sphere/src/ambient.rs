//! The ambient cube (Valve, McTaggart 2004) and ambient dice (Iwanicki & Sloan, "Ambient Dice",
//! JCGT 2017), SRBF and hybrid cubic Bezier variants.
use std::sync::OnceLock;

use glam::{DMat3, DVec3, Vec3};
use ndarray::Array2;
use prt_core::SphericalBasis;

use crate::sampling::sphere_quadrature;

/// Six clamped cos² lobes on ±X, ±Y, ±Z: `B_{±a}(v) = max(0, ±v_a)²`. They sum to 1 everywhere.
/// Order: +X, −X, +Y, −Y, +Z, −Z.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AmbientCube;

impl SphericalBasis for AmbientCube {
    fn len(&self) -> usize {
        6
    }

    fn eval(&self, dir: Vec3, out: &mut [f32]) {
        let c = dir.to_array();
        for a in 0..3 {
            let v = c[a];
            out[2 * a] = if v > 0.0 { v * v } else { 0.0 };
            out[2 * a + 1] = if v < 0.0 { v * v } else { 0.0 };
        }
    }

    /// Exact: `∫_{x>0} x⁴ = 2π/5`, `∫_{x>0,y>0} x² y² = π/15`, opposite lobes do not overlap.
    fn gram(&self) -> Array2<f64> {
        use std::f64::consts::PI;
        Array2::from_shape_fn((6, 6), |(i, j)| {
            if i == j {
                2.0 * PI / 5.0
            } else if i / 2 == j / 2 {
                0.0
            } else {
                PI / 15.0
            }
        })
    }

    fn name(&self) -> String {
        "ambient cube (6)".into()
    }
}

/// Ambient dice, SRBF variant: 12 lobes on the icosahedron's vertices. For each of the six
/// vertex pairs `±a_k`, `d = v·a_k` selects the lobe on the side of `v` and weighs it
/// `0.7 (d²/2) + 0.3 (5/6) d⁴` (Iwanicki & Sloan 2017, §4; the weights as in Probulator's
/// `AmbientDice::srbfWeights`). Lobe `2k` is `+a_k`, `2k + 1` is `−a_k`; the axes `a_k` are
/// Probulator's `(1,t,0), (−1,t,0), (0,1,t), (0,−1,t), (t,0,1), (t,0,−1)`, `t = 1/φ`.
///
/// The Gram matrix is a 256 × 512 Gauss-Legendre product quadrature (the lobes have a kink on
/// a great circle, so it is accurate to about 1e-6 relative, not exact).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AmbientDiceSrbf;

impl AmbientDiceSrbf {
    /// The six (normalised) vertex axes.
    pub fn axes() -> [Vec3; 6] {
        let t = 0.618_034_f32;
        [
            Vec3::new(1.0, t, 0.0).normalize(),
            Vec3::new(-1.0, t, 0.0).normalize(),
            Vec3::new(0.0, 1.0, t).normalize(),
            Vec3::new(0.0, -1.0, t).normalize(),
            Vec3::new(t, 0.0, 1.0).normalize(),
            Vec3::new(t, 0.0, -1.0).normalize(),
        ]
    }
}

impl SphericalBasis for AmbientDiceSrbf {
    fn len(&self) -> usize {
        12
    }

    fn eval(&self, dir: Vec3, out: &mut [f32]) {
        let out = &mut out[..12];
        out.fill(0.0);
        for (k, a) in Self::axes().iter().enumerate() {
            let d = dir.dot(*a);
            let c2 = d * d;
            let w = 0.7 * (0.5 * c2) + 0.3 * (5.0 / 6.0 * c2 * c2);
            out[if d > 0.0 { 2 * k } else { 2 * k + 1 }] = w;
        }
    }

    fn gram(&self) -> Array2<f64> {
        quadrature_gram(self, 256)
    }

    fn name(&self) -> String {
        "ambient dice SRBF (12)".into()
    }
}

/// `t = 1/φ`: the icosahedron's vertices are the cyclic permutations of `(±1, ±t, 0)`.
const T: f64 = 0.618_033_988_749_894_9;

/// Ambient dice, hybrid cubic Bezier variant (Iwanicki & Sloan 2017, §3): 36 functions, a
/// value and two tangential derivatives at each of the 12 icosahedron vertices, blended over
/// each of the 20 spherical triangles by a cubic Bezier triangle whose central control point
/// is a barycentric-weighted blend of three C¹-motivated choices ("hybrid").
///
/// Function `3v` is the value at vertex `v`, `3v + 1` and `3v + 2` the derivatives along the
/// vertex's tangent and bitangent. Vertices, their order and tangents, the triangle
/// selection (octant plus three plane tests) and the constants `a₀, a₁, a₂` and `1/√5` follow
/// Probulator's `AmbientDice` (kayru/Probulator, `ExperimentAmbientDice`), so coefficients are
/// interchangeable with it. The barycentric normals and derivative factors are derived here:
/// the normals `n_i` of triangle `(v₀, v₁, v₂)` are the rows of `[v̂₀ v̂₁ v̂₂]⁻¹` (so
/// `b_i = n_i·d` are the planar barycentrics of `d` scaled by its ray distance; they do not sum
/// to 1 on the sphere), and the factor of the Bezier control point next to `v_i` on edge
/// `v_i v_j` is `(V_j − V_i)·T_i / 3α` with `V` the unnormalised vertices (edge length 2),
/// `T_i` the tangent (bitangent) and `α = ½ √((5 + √5)/2)`, as Probulator's comment says.
///
/// Differences from Probulator, both at rounding level: barycentrics are clamped at 0 (a
/// direction on a triangle edge can round to `−1e-8`, which Probulator's `b₁b₂/(b₀b₁ + …)`
/// blend weights turn into large values), and when two barycentrics are 0 (exactly at a
/// vertex) the blend weights, whose control point then has weight 0, are 0 instead of 0/0.
///
/// The basis is neither orthonormal nor non-negative (derivative functions change sign). The
/// Gram matrix is a 512 × 1024 Gauss-Legendre product quadrature (the functions have kinks on
/// the triangle edges, so it is accurate to about 1e-6 relative, not exact), computed once.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AmbientDiceBezier;

/// Per-triangle data of [`AmbientDiceBezier`], derived once from the geometry.
#[derive(Debug)]
struct BezierTables {
    /// Vertex indices of each triangle.
    triangles: [[usize; 3]; 20],
    /// Barycentric normals `n_i` (`n_i · v̂_j = δ_ij`).
    normals: [[Vec3; 3]; 20],
    /// Tangent and bitangent factors of the edge control points, in the order
    /// `(0→1, 0→2, 1→0, 1→2, 2→0, 2→1)` (control point next to the first vertex).
    tangent_factors: [[f32; 6]; 20],
    bitangent_factors: [[f32; 6]; 20],
    gram: OnceLock<Array2<f64>>,
}

/// The ordered vertex pairs of a triangle's edge control points (see `BezierTables`).
const EDGES: [(usize, usize); 6] = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)];

impl AmbientDiceBezier {
    /// Index of vertex `(±1, ±t, 0)`: `x_neg`, `y_neg` are the sign bits.
    fn vertex_a(x_neg: usize, y_neg: usize) -> usize {
        2 * y_neg + x_neg
    }
    /// Index of vertex `(0, ±1, ±t)`.
    fn vertex_b(y_neg: usize, z_neg: usize) -> usize {
        4 + 2 * z_neg + y_neg
    }
    /// Index of vertex `(±t, 0, ±1)`.
    fn vertex_c(x_neg: usize, z_neg: usize) -> usize {
        8 + 2 * z_neg + x_neg
    }

    /// The 12 unnormalised vertices `V_v` (length `√(1 + t²)`), in coefficient order.
    pub fn vertices() -> [DVec3; 12] {
        let sign = |neg: usize| if neg == 1 { -1.0 } else { 1.0 };
        let mut v = [DVec3::ZERO; 12];
        for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            v[Self::vertex_a(a, b)] = DVec3::new(sign(a), sign(b) * T, 0.0);
            v[Self::vertex_b(a, b)] = DVec3::new(0.0, sign(a), sign(b) * T);
            v[Self::vertex_c(a, b)] = DVec3::new(sign(a) * T, 0.0, sign(b));
        }
        v
    }

    /// The unit tangent `T_v` of every vertex (Probulator's choice); the bitangent is
    /// `v̂ × T_v`.
    pub fn tangents() -> [DVec3; 12] {
        let s5 = 5.0f64.sqrt();
        let (a, b) = ((1.0 - 1.0 / s5) / 2.0, 1.0 / s5);
        let c = ((5.0 + s5) / 10.0).sqrt();
        let d = ((5.0 - s5) / 10.0).sqrt();
        [
            DVec3::new(a, -b, -c),
            DVec3::new(a, b, c),
            DVec3::new(a, b, c),
            DVec3::new(a, -b, c),
            DVec3::X,
            DVec3::X,
            DVec3::X,
            DVec3::X,
            DVec3::new(c, 0.0, -d),
            DVec3::new(c, 0.0, d),
            DVec3::new(c, 0.0, d),
            DVec3::new(c, 0.0, -d),
        ]
    }

    /// The 20 triangles: 8 in the octants, then 4 across each of the planes x = 0, y = 0
    /// and z = 0.
    pub fn triangles() -> [[usize; 3]; 20] {
        let mut t = [[0usize; 3]; 20];
        for (i, tri) in t.iter_mut().enumerate() {
            *tri = match i {
                0..8 => {
                    let (x, y, z) = (i & 1, (i >> 1) & 1, i >> 2);
                    [
                        Self::vertex_a(x, y),
                        Self::vertex_b(y, z),
                        Self::vertex_c(x, z),
                    ]
                }
                8..12 => {
                    let (y, z) = ((i - 8) & 1, (i - 8) >> 1);
                    [
                        Self::vertex_b(y, z),
                        Self::vertex_c(0, z),
                        Self::vertex_c(1, z),
                    ]
                }
                12..16 => {
                    let (x, z) = ((i - 12) & 1, (i - 12) >> 1);
                    [
                        Self::vertex_a(x, 0),
                        Self::vertex_a(x, 1),
                        Self::vertex_c(x, z),
                    ]
                }
                _ => {
                    let (x, y) = ((i - 16) & 1, (i - 16) >> 1);
                    [
                        Self::vertex_a(x, y),
                        Self::vertex_b(y, 0),
                        Self::vertex_b(y, 1),
                    ]
                }
            };
        }
        t
    }

    /// The triangle containing direction `d`: the octant's triangle unless one of three plane
    /// tests moves it to a neighbour across a coordinate plane.
    pub fn triangle_of(d: Vec3) -> usize {
        let (x, y, z) = (
            usize::from(d.x < 0.0),
            usize::from(d.y < 0.0),
            usize::from(d.z < 0.0),
        );
        let a = d.abs();
        let (t, t2) = (T as f32, (T * T) as f32);
        let mut tri = x + 2 * y + 4 * z;
        if a.x + t2 * a.y - t * a.z <= 0.0 {
            tri = 8 + y + 2 * z;
        }
        if -t * a.x + a.y + t2 * a.z <= 0.0 {
            tri = 12 + x + 2 * z;
        }
        if t2 * a.x - t * a.y + a.z <= 0.0 {
            tri = 16 + x + 2 * y;
        }
        tri
    }

    fn tables() -> &'static BezierTables {
        static TABLES: OnceLock<BezierTables> = OnceLock::new();
        TABLES.get_or_init(|| {
            let verts = Self::vertices();
            let tangents = Self::tangents();
            let bitangents: [DVec3; 12] =
                std::array::from_fn(|v| verts[v].normalize().cross(tangents[v]));
            let alpha = 0.5 * (0.5 * (5.0 + 5.0f64.sqrt())).sqrt();
            let triangles = Self::triangles();
            let mut normals = [[Vec3::ZERO; 3]; 20];
            let mut tangent_factors = [[0.0f32; 6]; 20];
            let mut bitangent_factors = [[0.0f32; 6]; 20];
            for (t, tri) in triangles.iter().enumerate() {
                let m = DMat3::from_cols(
                    verts[tri[0]].normalize(),
                    verts[tri[1]].normalize(),
                    verts[tri[2]].normalize(),
                );
                let rows = m.inverse().transpose();
                for i in 0..3 {
                    normals[t][i] = rows.col(i).as_vec3();
                }
                for (e, &(i, j)) in EDGES.iter().enumerate() {
                    let edge = verts[tri[j]] - verts[tri[i]];
                    tangent_factors[t][e] = (edge.dot(tangents[tri[i]]) / (3.0 * alpha)) as f32;
                    bitangent_factors[t][e] = (edge.dot(bitangents[tri[i]]) / (3.0 * alpha)) as f32;
                }
            }
            BezierTables {
                triangles,
                normals,
                tangent_factors,
                bitangent_factors,
                gram: OnceLock::new(),
            }
        })
    }

    /// The weights of the 9 functions of the triangle containing `d`: the triangle's vertices
    /// and, per vertex, `[value, tangent derivative, bitangent derivative]`.
    pub fn weights(d: Vec3) -> ([usize; 3], [[f32; 3]; 3]) {
        let tables = Self::tables();
        let tri = Self::triangle_of(d);
        let n = &tables.normals[tri];
        let b = [0, 1, 2].map(|i| n[i].dot(d).max(0.0));
        // The central control point, 6 b₀b₁b₂, is shared between three choices, one per
        // vertex k, blended by m_k ∝ (product of the other two barycentrics).
        let pair = [b[1] * b[2], b[0] * b[2], b[0] * b[1]];
        let sum = pair[0] + pair[1] + pair[2];
        let centre = 6.0 * b[0] * b[1] * b[2];
        let m = if sum > 0.0 {
            pair.map(|p| centre * p / sum)
        } else {
            [0.0; 3]
        };
        let s5 = 5.0f32.sqrt();
        let a0 = (s5 - 5.0) / 40.0;
        let a1 = (11.0 * s5 - 15.0) / 40.0;
        let a2 = s5 / 10.0;
        let value_factor = 1.0 / s5;
        let mut w = [[0.0f32; 3]; 3];
        for i in 0..3 {
            // Choice k adds a₀ to the values of the two vertices other than k.
            w[i][0] = b[i] * b[i] * b[i] + a0 * (m[0] + m[1] + m[2] - m[i]);
        }
        for (e, &(i, j)) in EDGES.iter().enumerate() {
            // Edge control point next to v_i towards v_j: Bernstein 3 b_i² b_j, plus a₁ from
            // the choice of the opposite vertex and a₂ from the choice of v_j.
            let opposite = 3 - i - j;
            let c = 3.0 * b[i] * b[i] * b[j] + a1 * m[opposite] + a2 * m[j];
            w[i][0] += value_factor * c;
            w[i][1] += tables.tangent_factors[tri][e] * c;
            w[i][2] += tables.bitangent_factors[tri][e] * c;
        }
        (tables.triangles[tri], w)
    }
}

impl SphericalBasis for AmbientDiceBezier {
    fn len(&self) -> usize {
        36
    }

    fn eval(&self, dir: Vec3, out: &mut [f32]) {
        let out = &mut out[..36];
        out.fill(0.0);
        let (verts, w) = Self::weights(dir);
        for (v, w) in verts.iter().zip(w) {
            out[3 * v..3 * v + 3].copy_from_slice(&w);
        }
    }

    fn gram(&self) -> Array2<f64> {
        Self::tables()
            .gram
            .get_or_init(|| quadrature_gram(self, 512))
            .clone()
    }

    fn name(&self) -> String {
        "ambient dice Bezier (36)".into()
    }
}

/// Gram matrix of any basis by a product Gauss-Legendre quadrature with `n` polar nodes.
pub fn quadrature_gram(basis: &dyn SphericalBasis, n: usize) -> Array2<f64> {
    let k = basis.len();
    let (dirs, weights) = sphere_quadrature(n);
    let mut g = Array2::<f64>::zeros((k, k));
    let mut b = vec![0.0f32; k];
    for (d, w) in dirs.iter().zip(&weights) {
        basis.eval(*d, &mut b);
        for i in 0..k {
            if b[i] == 0.0 {
                continue;
            }
            let wi = w * b[i] as f64;
            for j in i..k {
                g[[i, j]] += wi * b[j] as f64;
            }
        }
    }
    for i in 0..k {
        for j in 0..i {
            g[[i, j]] = g[[j, i]];
        }
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The derived tables against entries of Probulator's hard-coded ones
    /// (`triangleBarycentricNormals`, `triDerivativeTangentFactors`,
    /// `triDerivativeBitangentFactors`, `bitangents`).
    #[test]
    fn derived_tables_match_probulators() {
        let t = AmbientDiceBezier::tables();
        let close = |a: f32, b: f32| (a - b).abs() < 2e-6;
        let n0 = [0.9510565, 0.36327127, -0.58778524];
        assert!((0..3).all(|i| close(t.normals[0][0][i], n0[i])));
        let n9 = [0.0, -1.1755705, 0.0];
        assert!((0..3).all(|i| close(t.normals[9][0][i], n9[i])));
        let n19 = [0.36327127, -0.58778524, -0.9510565];
        assert!((0..3).all(|i| close(t.normals[19][2][i], n19[i])));
        let tf0 = [
            -0.34100485,
            -0.238272,
            0.3504874,
            0.21661313,
            0.2981424,
            -0.11388027,
        ];
        let tf13 = [
            -0.1937447, 0.238272, -0.1937447, 0.238272, -0.2981424, -0.2981424,
        ];
        let bf2 = [
            0.36749536,
            0.08738982,
            -0.11388027,
            0.2981424,
            -0.21661313,
            -0.3504874,
        ];
        let bf16 = [
            0.1397348,
            0.36749536,
            0.11388027,
            0.36852428,
            -0.11388027,
            -0.36852428,
        ];
        for e in 0..6 {
            assert!(close(t.tangent_factors[0][e], tf0[e]), "tangent 0 {e}");
            assert!(close(t.tangent_factors[13][e], tf13[e]), "tangent 13 {e}");
            assert!(close(t.bitangent_factors[2][e], bf2[e]), "bitangent 2 {e}");
            assert!(
                close(t.bitangent_factors[16][e], bf16[e]),
                "bitangent 16 {e}"
            );
        }
        let tri = AmbientDiceBezier::triangles();
        assert_eq!(tri[0], [0, 4, 8]);
        assert_eq!(tri[9], [5, 8, 9]);
        assert_eq!(tri[14], [0, 2, 10]);
        assert_eq!(tri[19], [3, 5, 7]);
    }
}
