//! The tensor Gauss–Legendre quadrature of the hat-grid basis: per-axis points and kernel
//! data, and the assembly of both exact systems per basis cell.

use super::*;

/// 3-point Gauss–Legendre rule on [−1, 1]: exact for polynomials of degree ≤ 5.
pub(super) const GAUSS_NODES: [f64; 3] = [-0.774_596_669_241_483_4, 0.0, 0.774_596_669_241_483_4];
pub(super) const GAUSS_WEIGHTS: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];
/// The basis domain per axis in voxels from the field's lower face, or `None` unless it lies
/// inside the field's box with a positive extent. Ends within 1e-5 voxels of a half voxel are
/// snapped to it (the voxel-centre box of [`crate::expert::basis_box`] is computed in f32), so that
/// they coincide with the voxel-centre breakpoints.
pub(super) fn basis_spans(field: &GridField, domain: prt_core::Aabb) -> Option<[(f64, f64); 3]> {
    let (bounds, size, dims) = (field.bounds(), field.voxel_size(), field.dims());
    let mut spans = [(0.0, 0.0); 3];
    for k in 0..3 {
        let to_voxels = |x: f32| {
            let u = (f64::from(x) - f64::from(bounds.min[k])) / f64::from(size[k]);
            let half = (2.0 * u).round() / 2.0;
            if (u - half).abs() < 1e-5 { half } else { u }
        };
        let (lo, hi) = (to_voxels(domain.min[k]), to_voxels(domain.max[k]));
        if !(lo >= 0.0 && hi <= dims[k] as f64 && hi > lo) {
            return None;
        }
        spans[k] = (lo, hi);
    }
    Some(spans)
}

/// One quadrature point along an axis, with the 1D kernel data there.
#[derive(Debug, Clone, Copy)]
pub(super) struct AxisPoint {
    /// Weight (interval length × Gauss weight, in voxels).
    pub(super) w: f64,
    /// Lower voxel (coefficient node) of the coefficient / target interpolation, and the hat
    /// weight of the upper one.
    pub(super) ci: usize,
    pub(super) ct: f64,
    /// Basis cell and the hat weight of its upper node.
    pub(super) bi: usize,
    pub(super) bt: f64,
}

/// The quadrature points of one axis, in increasing order.
pub(super) struct Axis {
    pub(super) points: Vec<AxisPoint>,
    /// Points of each basis cell.
    pub(super) basis_cells: Vec<Range<usize>>,
}

impl Axis {
    /// `voxels ≥ 2` voxels, `nodes ≥ 2` basis nodes spanning `[lo, hi]` (in voxels from the
    /// field's lower face, `0 ≤ lo < hi ≤ voxels`; the basis is constant outside it, as a hat
    /// grid is clamped).
    pub(super) fn new(voxels: usize, nodes: usize, (lo, hi): (f64, f64)) -> Axis {
        let n = voxels as f64;
        let cells = nodes - 1;
        let mut breaks: Vec<f64> = (0..voxels)
            .map(|i| i as f64 + 0.5)
            .chain((0..nodes).map(|k| lo + (hi - lo) * k as f64 / cells as f64))
            .chain([0.0, n])
            .collect();
        breaks.sort_by(f64::total_cmp);
        breaks.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        let mut points = Vec::with_capacity(3 * breaks.len());
        for pair in breaks.windows(2) {
            let (mid, half) = (0.5 * (pair[0] + pair[1]), 0.5 * (pair[1] - pair[0]));
            for (xi, wi) in GAUSS_NODES.iter().zip(GAUSS_WEIGHTS) {
                let u = mid + half * xi;
                let uc = (u - 0.5).clamp(0.0, n - 1.0);
                let ci = (uc.floor() as usize).min(voxels - 2);
                let ub = ((u - lo) * cells as f64 / (hi - lo)).clamp(0.0, cells as f64);
                let bi = (ub.floor() as usize).min(cells - 1);
                points.push(AxisPoint {
                    w: half * wi,
                    ci,
                    ct: uc - ci as f64,
                    bi,
                    bt: ub - bi as f64,
                });
            }
        }
        let basis_cells = (0..cells)
            .map(|cell| {
                let lo = points.partition_point(|p| p.bi < cell);
                let hi = points.partition_point(|p| p.bi <= cell);
                lo..hi
            })
            .collect();
        Axis {
            points,
            basis_cells,
        }
    }

    /// The first voxel and the number of voxels the points `range` touch.
    pub(super) fn voxel_span(&self, range: &Range<usize>) -> (usize, usize) {
        let lo = self.points[range.start].ci;
        let hi = self.points[range.end - 1].ci + 1;
        (lo, hi - lo + 1)
    }
}

/// The tensor quadrature of a field with the hat grids of [`crate::Mbd`].
pub(super) struct Quadrature {
    pub(super) axes: [Axis; 3],
    pub(super) voxels: [usize; 3],
    pub(super) nodes: [usize; 3],
}

/// Kernel data at one quadrature point, corners in bit order (bit 0 = x, 1 = y, 2 = z).
pub(super) struct Point {
    pub(super) w: f64,
    pub(super) phi: [f64; 8],
    /// Voxel (coefficient node) of each corner, local to the basis cell's voxel block.
    pub(super) local: [usize; 8],
    pub(super) psi: [f64; 8],
}

/// The voxel block a basis cell's points touch.
pub(super) struct Span {
    pub(super) lo: [usize; 3],
    pub(super) len: [usize; 3],
}

impl Span {
    pub(super) fn count(&self) -> usize {
        self.len.iter().product()
    }

    /// Global flat voxel index of local voxel `v`.
    pub(super) fn global(&self, v: usize, voxels: [usize; 3]) -> usize {
        let [ex, ey, _] = self.len;
        let (x, y, z) = (v % ex, v / ex % ey, v / (ex * ey));
        self.lo[0] + x + voxels[0] * (self.lo[1] + y + voxels[1] * (self.lo[2] + z))
    }

    /// The field's vectors of the block, `count × D` in f64.
    pub(super) fn gather(&self, field: &GridField, voxels: [usize; 3]) -> Array2<f64> {
        let d = field.dim();
        let mut f = Array2::<f64>::zeros((self.count(), d));
        for (v, mut row) in f.rows_mut().into_iter().enumerate() {
            for (o, &x) in row.iter_mut().zip(field.voxel(self.global(v, voxels))) {
                *o = x as f64;
            }
        }
        f
    }
}

impl Quadrature {
    /// The quadrature for a basis hat grid over a box inside the field's.
    pub(super) fn new(field: &GridField, basis: &HatGrid) -> Result<Quadrature, MbdError> {
        let voxels = field.dims();
        let nodes = basis.nodes();
        let spans = basis_spans(field, basis.domain()).filter(|_| nodes.iter().all(|&n| n >= 2));
        let Some(spans) = spans else {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: "the polish needs a hat grid of at least 2 nodes per axis over a box inside \
                      the field's"
                    .into(),
            });
        };
        Ok(Quadrature {
            axes: [0, 1, 2].map(|k| Axis::new(voxels[k], nodes[k], spans[k])),
            voxels,
            nodes,
        })
    }

    pub(super) fn cells(&self) -> [usize; 3] {
        self.nodes.map(|n| n - 1)
    }

    pub(super) fn num_cells(&self) -> usize {
        self.cells().iter().product()
    }

    pub(super) fn cell_coords(&self, cell: usize) -> [usize; 3] {
        let [cx, cy, _] = self.cells();
        [cell % cx, cell / cx % cy, cell / (cx * cy)]
    }

    /// Flat basis node of corner `n` of basis cell `cell`.
    pub(super) fn basis_node(&self, cell: [usize; 3], n: usize) -> usize {
        let [nx, ny, _] = self.nodes;
        (cell[0] + (n & 1)) + nx * ((cell[1] + (n >> 1 & 1)) + ny * (cell[2] + (n >> 2 & 1)))
    }

    /// The point ranges of basis cell `cell` and the voxel block they touch.
    pub(super) fn cell_points(&self, cell: [usize; 3]) -> ([Range<usize>; 3], Span) {
        let ranges = [0, 1, 2].map(|k| self.axes[k].basis_cells[cell[k]].clone());
        let spans = [0, 1, 2].map(|k| self.axes[k].voxel_span(&ranges[k]));
        let span = Span {
            lo: spans.map(|s| s.0),
            len: spans.map(|s| s.1),
        };
        (ranges, span)
    }

    /// Calls `visit` for every point of `ranges`, with its kernel data local to `span`.
    pub(super) fn for_points(
        &self,
        ranges: &[Range<usize>; 3],
        span: &Span,
        mut visit: impl FnMut(&Point),
    ) {
        let [ex, ey, _] = span.len;
        let mut point = Point {
            w: 0.0,
            phi: [0.0; 8],
            local: [0; 8],
            psi: [0.0; 8],
        };
        for pz in &self.axes[2].points[ranges[2].clone()] {
            for py in &self.axes[1].points[ranges[1].clone()] {
                for px in &self.axes[0].points[ranges[0].clone()] {
                    let p = [px, py, pz];
                    point.w = px.w * py.w * pz.w;
                    let base = (px.ci - span.lo[0])
                        + ex * ((py.ci - span.lo[1]) + ey * (pz.ci - span.lo[2]));
                    for corner in 0..8 {
                        let bit = |k: usize| corner >> k & 1;
                        let hat = |k: usize, t: f64| if bit(k) == 1 { t } else { 1.0 - t };
                        point.phi[corner] = hat(0, p[0].ct) * hat(1, p[1].ct) * hat(2, p[2].ct);
                        point.psi[corner] = hat(0, p[0].bt) * hat(1, p[1].bt) * hat(2, p[2].bt);
                        point.local[corner] = base + bit(0) + ex * (bit(1) + ey * bit(2));
                    }
                    visit(&point);
                }
            }
        }
    }

    /// `∫ ‖f‖² dx` of the field's trilinear interpolation.
    pub(super) fn energy(&self, field: &GridField) -> f64 {
        trilinear_energy_with(
            field,
            [0, 1, 2].map(|k| mass_matrix(&self.axes[k], self.voxels[k])),
        )
    }

    /// The basis step's normal equations at coefficients `c`.
    pub(super) fn basis_system(
        &self,
        field: &GridField,
        c: &[f64],
        l: usize,
        progress: &dyn Progress,
    ) -> Result<BasisSystem, MbdError> {
        let d = field.dim();
        let unknowns = self.nodes.iter().product::<usize>() * l;
        let cells: Vec<Result<CellBasisSystem, MbdError>> = (0..self.num_cells())
            .into_par_iter()
            .map(|cell| {
                progress.check()?;
                let (ranges, span) = self.cell_points(self.cell_coords(cell));
                let width = 8 * l;
                let mut weights = Array2::<f64>::zeros((span.count(), width));
                let mut gram = Array2::<f64>::zeros((width, width));
                let mut z = vec![0.0; width];
                let mut cx = vec![0.0; l];
                let local_c: Vec<f64> = (0..span.count())
                    .flat_map(|v| {
                        let g = span.global(v, self.voxels);
                        c[g * l..(g + 1) * l].iter().copied()
                    })
                    .collect();
                let weights_flat = weights.as_slice_mut().unwrap_or(&mut []);
                // Rows √w z of a batch of points: the Gram is their product, in one GEMM per
                // batch (fixed batches, so the sums do not depend on the thread count).
                let mut rows = Vec::with_capacity(GRAM_BATCH * width);
                let flush = |rows: &mut Vec<f64>, gram: &mut Array2<f64>| {
                    let count = rows.len() / width;
                    if let Ok(z) = ArrayView2::from_shape((count, width), rows.as_slice()) {
                        general_mat_mul(1.0, &z.t(), &z, 1.0, gram);
                    }
                    rows.clear();
                };
                self.for_points(&ranges, &span, |p| {
                    cx.fill(0.0);
                    for k in 0..8 {
                        let row = &local_c[p.local[k] * l..(p.local[k] + 1) * l];
                        for (o, &x) in cx.iter_mut().zip(row) {
                            *o += p.phi[k] * x;
                        }
                    }
                    for n in 0..8 {
                        for (o, &x) in z[n * l..(n + 1) * l].iter_mut().zip(&cx) {
                            *o = p.psi[n] * x;
                        }
                    }
                    let root = p.w.sqrt();
                    rows.extend(z.iter().map(|&x| root * x));
                    if rows.len() == GRAM_BATCH * width {
                        flush(&mut rows, &mut gram);
                    }
                    for k in 0..8 {
                        let wk = p.w * p.phi[k];
                        if wk == 0.0 {
                            continue;
                        }
                        let row = &mut weights_flat[p.local[k] * width..(p.local[k] + 1) * width];
                        for (o, &x) in row.iter_mut().zip(&z) {
                            *o += wk * x;
                        }
                    }
                });
                flush(&mut rows, &mut gram);
                let f = span.gather(field, self.voxels);
                let mut rhs = Array2::<f64>::zeros((width, d));
                general_mat_mul(1.0, &weights.t(), &f, 0.0, &mut rhs);
                Ok((gram, rhs))
            })
            .collect();
        let mut gram = Array2::<f64>::zeros((unknowns, unknowns));
        let mut rhs = Array2::<f64>::zeros((unknowns, d));
        for (cell, part) in cells.into_iter().enumerate() {
            let (g, r) = part?;
            let coords = self.cell_coords(cell);
            let global = |j: usize| self.basis_node(coords, j / l) * l + j % l;
            for (j, row) in g.rows().into_iter().enumerate() {
                let gj = global(j);
                for (k, &x) in row.iter().enumerate() {
                    gram[[gj, global(k)]] += x;
                }
                for (o, &x) in rhs.row_mut(gj).iter_mut().zip(r.row(j)) {
                    *o += x;
                }
            }
        }
        Ok(BasisSystem { gram, rhs })
    }

    /// Adds the coefficient step's normal equations at basis `b` (without the ridge) to
    /// `system`.
    pub(super) fn add_coefficient_system(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        system: &mut CoefficientSystem,
        progress: &dyn Progress,
    ) -> Result<(), MbdError> {
        let d = field.dim();
        let cells: Vec<usize> = (0..self.num_cells()).collect();
        for batch in cells.chunks(CELL_BATCH) {
            let parts: Vec<Result<Vec<BoxSystem>, MbdError>> = batch
                .par_iter()
                .map(|&cell| {
                    progress.check()?;
                    Ok(self.coefficient_boxes(field, b, l, d, cell))
                })
                .collect();
            for part in parts {
                for boxed in part? {
                    system.add(&boxed, self.voxels);
                }
            }
        }
        Ok(())
    }

    /// The coefficient-system contributions of basis cell `cell`, one per coefficient cell
    /// (box between 8 voxel centres) it overlaps.
    pub(super) fn coefficient_boxes(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        d: usize,
        cell: usize,
    ) -> Vec<BoxSystem> {
        let coords = self.cell_coords(cell);
        let (ranges, span) = self.cell_points(coords);
        let width = 8 * l;
        let ll = l * l;
        // The cell's basis rows (8L × D), their Gram K and their products with the voxels.
        let mut cell_basis = Array2::<f64>::zeros((width, d));
        for n in 0..8 {
            let node = self.basis_node(coords, n);
            for li in 0..l {
                let src = &b[(node * l + li) * d..(node * l + li + 1) * d];
                cell_basis
                    .row_mut(n * l + li)
                    .iter_mut()
                    .zip(src)
                    .for_each(|(o, &x)| *o = x);
            }
        }
        let mut gram = Array2::<f64>::zeros((width, width));
        general_mat_mul(1.0, &cell_basis, &cell_basis.t(), 0.0, &mut gram);
        let f = span.gather(field, self.voxels);
        let mut projected = Array2::<f64>::zeros((span.count(), width));
        general_mat_mul(1.0, &f, &cell_basis.t(), 0.0, &mut projected);
        let projected = projected.as_slice().unwrap_or(&[]);
        // K per node pair n ≤ n' (L × L), off-diagonal pairs symmetrised: M(x) = Σ ψ_n ψ_n' K_pair.
        let pairs: Vec<(usize, usize)> = (0..8).flat_map(|n| (n..8).map(move |m| (n, m))).collect();
        let pair_blocks: Vec<f64> = pairs
            .iter()
            .flat_map(|&(n, m)| {
                let gram = &gram;
                (0..ll).map(move |e| {
                    let (i, j) = (e / l, e % l);
                    let a = gram[[n * l + i, m * l + j]];
                    if n == m {
                        a
                    } else {
                        a + gram[[m * l + i, n * l + j]]
                    }
                })
            })
            .collect();
        let corner_pairs: Vec<(usize, usize)> =
            (0..8).flat_map(|k| (k..8).map(move |m| (k, m))).collect();
        // Split each axis' points into runs of equal coefficient cell.
        let runs = |k: usize| -> Vec<Range<usize>> {
            let points = &self.axes[k].points;
            let mut out: Vec<Range<usize>> = Vec::new();
            for i in ranges[k].clone() {
                match out.last_mut() {
                    Some(r) if points[r.start].ci == points[i].ci => r.end = i + 1,
                    _ => out.push(i..i + 1),
                }
            }
            out
        };
        let (rx, ry, rz) = (runs(0), runs(1), runs(2));
        let mut boxes = Vec::with_capacity(rx.len() * ry.len() * rz.len());
        let mut m = vec![0.0; ll];
        let mut s = vec![0.0; l];
        for z in &rz {
            for y in &ry {
                for x in &rx {
                    let box_ranges = [x.clone(), y.clone(), z.clone()];
                    let mut a = vec![0.0; corner_pairs.len() * ll];
                    let mut r = vec![0.0; 8 * l];
                    self.for_points(&box_ranges, &span, |p| {
                        m.fill(0.0);
                        for (pair, &(n, n2)) in pairs.iter().enumerate() {
                            let weight = p.psi[n] * p.psi[n2];
                            if weight == 0.0 {
                                continue;
                            }
                            for (o, &k) in
                                m.iter_mut().zip(&pair_blocks[pair * ll..(pair + 1) * ll])
                            {
                                *o += weight * k;
                            }
                        }
                        s.fill(0.0);
                        for k in 0..8 {
                            let row = &projected[p.local[k] * width..(p.local[k] + 1) * width];
                            for n in 0..8 {
                                let weight = p.phi[k] * p.psi[n];
                                for (o, &h) in s.iter_mut().zip(&row[n * l..(n + 1) * l]) {
                                    *o += weight * h;
                                }
                            }
                        }
                        for (pair, &(k, k2)) in corner_pairs.iter().enumerate() {
                            let weight = p.w * p.phi[k] * p.phi[k2];
                            if weight == 0.0 {
                                continue;
                            }
                            for (o, &x) in a[pair * ll..(pair + 1) * ll].iter_mut().zip(&m) {
                                *o += weight * x;
                            }
                        }
                        for k in 0..8 {
                            let weight = p.w * p.phi[k];
                            for (o, &x) in r[k * l..(k + 1) * l].iter_mut().zip(&s) {
                                *o += weight * x;
                            }
                        }
                    });
                    let p = &self.axes;
                    boxes.push(BoxSystem {
                        lower: [
                            p[0].points[x.start].ci,
                            p[1].points[y.start].ci,
                            p[2].points[z.start].ci,
                        ],
                        a,
                        r,
                    });
                }
            }
        }
        boxes
    }
}
