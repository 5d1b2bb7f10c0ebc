//! The two exact linear systems of the polish (basis given coefficients, coefficients given
//! basis), the block storage they share, and the dispatch between the hat-grid and
//! voxel-stored quadratures.

use super::*;

/// The voxels in columns of `COLUMN × COLUMN` voxels in x and y, each column plane by plane
/// (z, then y, then x), and where each column starts. Walking a column this way, the pair blocks
/// a voxel reads from its backward neighbours ([`pair_block`]) were read one plane before and
/// are still in cache (a plane of a column's blocks is 1.8 MB at L = 8), where a walk of the
/// whole grid in voxel order would fetch them again from memory once a plane's blocks outgrow
/// the cache (Sponza 96: 28 MB).
pub(super) fn column_order([nx, ny, nz]: [usize; 3]) -> (Vec<usize>, Vec<usize>) {
    let mut order = Vec::with_capacity(nx * ny * nz);
    let mut starts = vec![0];
    for y0 in (0..ny).step_by(COLUMN) {
        for x0 in (0..nx).step_by(COLUMN) {
            for z in 0..nz {
                for y in y0..(y0 + COLUMN).min(ny) {
                    order.extend((x0..(x0 + COLUMN).min(nx)).map(|x| x + nx * (y + ny * z)));
                }
            }
            starts.push(order.len());
        }
    }
    (order, starts)
}

/// The neighbours `u` of voxel `v` in its 3³ block that lie in the grid, with their index
/// `(dx+1) + 3(dy+1) + 9(dz+1)`.
pub(super) fn neighbours(
    v: usize,
    [nx, ny, nz]: [usize; 3],
) -> impl Iterator<Item = (usize, usize)> {
    let at = [v % nx, v / nx % ny, v / (nx * ny)];
    (0..27).filter_map(move |nbr| {
        // Coordinates shifted by one, so that −1 is 0.
        let q = [0, 1, 2].map(|k| at[k] + [nbr % 3, nbr / 3 % 3, nbr / 9][k]);
        if (0..3).any(|k| q[k] == 0 || q[k] > [nx, ny, nz][k]) {
            return None;
        }
        Some((nbr, (q[0] - 1) + nx * ((q[1] - 1) + ny * (q[2] - 1))))
    })
}

/// The stored block of the pair of voxel `v` and its neighbour `u` (neighbour index `nbr`):
/// stored by `v` when `u` is a forward neighbour, else by `u` (then transposed as seen from
/// `v`, which makes no difference to the symmetric blocks the polish stores).
pub(super) fn pair_block(v: usize, u: usize, nbr: usize) -> usize {
    if nbr >= SELF_BLOCK {
        v * STORED_BLOCKS + nbr - SELF_BLOCK
    } else {
        u * STORED_BLOCKS + SELF_BLOCK - nbr
    }
}

/// The exact systems of a model's basis family.
pub(super) enum Systems<'a> {
    Hat(Quadrature),
    Voxels(VoxelQuadrature<'a>),
}

impl<'a> Systems<'a> {
    /// Checks the field, the model's kernels and shapes and the options.
    pub(super) fn new<B: PolishBasis>(
        field: &GridField,
        coefficient_kernels: &HatGrid,
        basis_kernels: &'a B,
        basis: &Array3<f32>,
        options: &PolishOptions,
    ) -> Result<Self, MbdError> {
        field.check_finite()?;
        let voxels = field.dims();
        let invalid = |which: &'static str, why: String| MbdError::InvalidKernels { which, why };
        if let Some(axis) = (0..3).find(|&k| voxels[k] < 2) {
            return Err(invalid(
                "coefficient",
                format!(
                    "the polish needs at least 2 voxels per axis (axis {axis} has {})",
                    voxels[axis]
                ),
            ));
        }
        let expected = HatGrid::new(voxels, voxel_centre_box(field))
            .map_err(|e| invalid("coefficient", e.to_string()))?;
        if *coefficient_kernels != expected {
            return Err(invalid(
                "coefficient",
                "the polish needs one hat per voxel centre of the field (as crate::Mbd)".into(),
            ));
        }
        let systems = match basis_kernels.layout() {
            BasisLayout::Hat(hats) => Systems::Hat(Quadrature::new(field, hats)?),
            BasisLayout::Voxels(weights) => {
                Systems::Voxels(VoxelQuadrature::new(field, weights, basis_kernels.len())?)
            }
        };
        let (n, l, d) = basis.dim();
        if n != basis_kernels.len() || d != field.dim() {
            return Err(MbdError::ShapeMismatch {
                what: "basis tensor",
                expected: vec![basis_kernels.len(), l, field.dim()],
                got: basis.shape().to_vec(),
            });
        }
        validate_options(options)?;
        check_basis_size(n, l)?;
        Ok(systems)
    }

    /// `∫ ‖f‖² dx` of the field's trilinear interpolation.
    pub(super) fn energy(&self, field: &GridField) -> f64 {
        match self {
            Systems::Hat(q) => q.energy(field),
            Systems::Voxels(_) => trilinear_energy(field),
        }
    }

    /// The basis step's normal equations at coefficients `c`; `scratch` is working memory
    /// (any length; the voxel-stored families use it for their neighbour blocks).
    pub(super) fn basis_system(
        &self,
        field: &GridField,
        c: &[f64],
        l: usize,
        scratch: &mut Vec<f64>,
        progress: &dyn Progress,
    ) -> Result<BasisSystem, MbdError> {
        match self {
            Systems::Hat(q) => q.basis_system(field, c, l, progress),
            Systems::Voxels(q) => q.basis_system(field, c, l, scratch, progress),
        }
    }

    /// The coefficient step's block-sparse normal equations at basis `b`, the ridge included,
    /// its blocks stored in `blocks` (any length; [`CoefficientSystem::into_blocks`] gives it
    /// back).
    pub(super) fn coefficient_system(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        lambda: f32,
        mut blocks: Vec<f64>,
        progress: &dyn Progress,
    ) -> Result<CoefficientSystem, MbdError> {
        let voxels = field.dims();
        let count: usize = voxels.iter().product();
        let ll = l * l;
        zeroed(&mut blocks, count * STORED_BLOCKS * ll);
        let mut system = CoefficientSystem {
            voxels,
            columns: column_order(voxels),
            rank: l,
            blocks,
            rhs: vec![0.0; count * l],
        };
        match self {
            Systems::Hat(q) => q.add_coefficient_system(field, b, l, &mut system, progress)?,
            Systems::Voxels(q) => q.add_coefficient_system(field, b, l, &mut system, progress)?,
        }
        symmetrise(&mut system.blocks, l);
        let half_lambda = 0.5 * lambda as f64;
        for v in 0..count {
            let own = v * STORED_BLOCKS;
            let block = &mut system.blocks[own * ll..(own + 1) * ll];
            for i in 0..l {
                block[i * l + i] += half_lambda;
            }
        }
        Ok(system)
    }
}

/// One coefficient cell's share of the coefficient system: corner pairs `k ≤ k'` (`L × L`
/// each) and per-corner right-hand sides.
pub(super) struct BoxSystem {
    pub(super) lower: [usize; 3],
    pub(super) a: Vec<f64>,
    pub(super) r: Vec<f64>,
}

/// One basis cell's share of the basis system: `8L × 8L` Gram and `8L × D` right-hand side.
pub(super) type CellBasisSystem = (Array2<f64>, Array2<f64>);

/// `G vec(B) = R`: the basis step's normal equations (`N·L × N·L`, `N·L × D`).
pub(super) struct BasisSystem {
    pub(super) gram: Array2<f64>,
    pub(super) rhs: Array2<f64>,
}

impl BasisSystem {
    /// `Σ_d b_dᵀ G b_d − 2 Σ R∘B`: the data term minus `∫‖f‖²`.
    pub(super) fn quadratic(&self, b: &Array2<f64>) -> f64 {
        let mut gb = Array2::<f64>::zeros(b.dim());
        general_mat_mul(1.0, &self.gram, b, 0.0, &mut gb);
        gb.iter()
            .zip(b.iter())
            .zip(self.rhs.iter())
            .map(|((&g, &x), &r)| x * (g - 2.0 * r))
            .sum()
    }

    /// The basis step: `b` replaced by the minimiser unless that raises the quadratic (by
    /// rounding); the new quadratic if it was.
    pub(super) fn step(&self, b: &mut Array2<f64>) -> Result<Option<f64>, MbdError> {
        let before = self.quadratic(b);
        let trial = self.solve()?;
        let after = self.quadratic(&trial);
        Ok((after <= before).then(|| {
            *b = trial;
            after
        }))
    }

    /// The minimiser, rounded to f32. A relative ridge (grown until the factorisation succeeds)
    /// keeps nodes without data (all their coefficients zero) solvable.
    pub(super) fn solve(&self) -> Result<Array2<f64>, MbdError> {
        let n = self.gram.nrows();
        let trace: f64 = self.gram.diag().sum();
        if trace <= 0.0 {
            return Ok(Array2::zeros(self.rhs.dim()));
        }
        let mut ridge = 1e-13 * trace / n as f64;
        let solution = loop {
            match prt_linalg::cholesky_solve(self.gram.view(), self.rhs.view(), ridge) {
                Ok(x) => break x,
                Err(prt_linalg::LinalgError::NotPositiveDefinite { .. })
                    if ridge < 1e-2 * trace =>
                {
                    ridge *= 100.0
                }
                Err(e) => return Err(linalg_error("polish basis step", e)),
            }
        };
        Ok(solution.mapv(round_f32))
    }
}

/// The coefficient step's normal equations: `L × L` blocks between each voxel and its 3³
/// neighbours, each pair's stored once ([`STORED_BLOCKS`], [`pair_block`]), the ridge included.
pub(super) struct CoefficientSystem {
    pub(super) voxels: [usize; 3],
    /// The voxels in [`column_order`], for [`CoefficientSystem::apply`].
    pub(super) columns: (Vec<usize>, Vec<usize>),
    pub(super) rank: usize,
    pub(super) blocks: Vec<f64>,
    pub(super) rhs: Vec<f64>,
}

impl CoefficientSystem {
    /// The storage of the blocks, for reuse.
    pub(super) fn into_blocks(self) -> Vec<f64> {
        self.blocks
    }

    pub(super) fn add(&mut self, boxed: &BoxSystem, voxels: [usize; 3]) {
        let l = self.rank;
        add_pair_blocks(&mut self.blocks, l * l, boxed.lower, &boxed.a, voxels);
        for k in 0..8 {
            let vk = corner_voxel(boxed.lower, k, voxels);
            for (o, &x) in self.rhs[vk * l..(vk + 1) * l]
                .iter_mut()
                .zip(&boxed.r[k * l..(k + 1) * l])
            {
                *o += x;
            }
        }
    }

    /// `y = A x`, column by column ([`column_order`]; each `y_v` is summed in the same order on
    /// any thread count).
    pub(super) fn apply(&self, x: &[f64], y: &mut [f64]) {
        let l = self.rank;
        let ll = l * l;
        let (order, starts) = &self.columns;
        let columns: Vec<Vec<f64>> = starts
            .par_windows(2)
            .map(|range| {
                let voxels = &order[range[0]..range[1]];
                let mut out = vec![0.0; voxels.len() * l];
                for (yv, &v) in out.chunks_mut(l).zip(voxels) {
                    for (nbr, u) in neighbours(v, self.voxels) {
                        let stored = pair_block(v, u, nbr);
                        let block = &self.blocks[stored * ll..(stored + 1) * ll];
                        let xu = &x[u * l..(u + 1) * l];
                        // Every block is symmetric (made exactly so by `symmetrise`), so it
                        // serves both voxels of its pair, and y += A x runs along its rows:
                        // L axpys that vectorise.
                        for (row, &xj) in block.chunks(l).zip(xu) {
                            for (o, &a) in yv.iter_mut().zip(row) {
                                *o += a * xj;
                            }
                        }
                    }
                }
                out
            })
            .collect();
        for (column, range) in columns.iter().zip(starts.windows(2)) {
            for (yv, &v) in column.chunks(l).zip(&order[range[0]..range[1]]) {
                y[v * l..(v + 1) * l].copy_from_slice(yv);
            }
        }
    }

    /// `r − A x`.
    pub(super) fn residual(&self, x: &[f64]) -> Vec<f64> {
        let mut residual = vec![0.0; x.len()];
        self.apply(x, &mut residual);
        residual
            .iter_mut()
            .zip(&self.rhs)
            .for_each(|(o, &b)| *o = b - *o);
        residual
    }

    /// Block-Jacobi preconditioned conjugate gradients from `start`, whose residual
    /// [`CoefficientSystem::residual`] is `residual`; the solution rounded to f32, and the
    /// iterations taken.
    pub(super) fn solve(
        &self,
        start: &[f64],
        residual: Vec<f64>,
        options: &PolishOptions,
        progress: &dyn Progress,
    ) -> Result<(Vec<f64>, usize), MbdError> {
        let l = self.rank;
        let ll = l * l;
        let voxels = self.rhs.len() / l;
        // Factor the diagonal blocks (identity where a block is not positive definite).
        let factors: Vec<Option<Vec<f64>>> = (0..voxels)
            .into_par_iter()
            .map(|v| {
                let own = v * STORED_BLOCKS;
                let mut a = self.blocks[own * ll..(own + 1) * ll].to_vec();
                cholesky_in_place(&mut a, l).then_some(a)
            })
            .collect();
        let precondition = |r: &[f64], z: &mut [f64]| {
            z.par_chunks_mut(l)
                .zip(r.par_chunks(l))
                .zip(factors.par_iter())
                .for_each(|((z, r), f)| {
                    z.copy_from_slice(r);
                    if let Some(f) = f {
                        cholesky_solve_in_place(f, z, l, 1);
                    }
                });
        };
        let mut x = start.to_vec();
        let mut r = residual;
        let target = options.cg_tolerance * dot(&self.rhs, &self.rhs).sqrt();
        let mut z = vec![0.0; x.len()];
        precondition(&r, &mut z);
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let mut q = vec![0.0; x.len()];
        let mut iterations = 0;
        while iterations < options.max_cg_iterations && dot(&r, &r).sqrt() > target {
            progress.check()?;
            self.apply(&p, &mut q);
            let pq = dot(&p, &q);
            if pq.is_nan() || pq <= 0.0 {
                break;
            }
            let alpha = rz / pq;
            x.iter_mut().zip(&p).for_each(|(x, &p)| *x += alpha * p);
            r.iter_mut().zip(&q).for_each(|(r, &q)| *r -= alpha * q);
            precondition(&r, &mut z);
            let rz_next = dot(&r, &z);
            let beta = rz_next / rz;
            rz = rz_next;
            p.iter_mut().zip(&z).for_each(|(p, &z)| *p = z + beta * *p);
            iterations += 1;
        }
        if x.iter().any(|v| !v.is_finite()) {
            return Err(MbdError::Diverged {
                what: "polished coefficients",
                iteration: iterations,
            });
        }
        Ok((x.into_iter().map(round_f32).collect(), iterations))
    }
}

/// Makes each `l × l` block of `blocks` exactly symmetric, `(X + Xᵀ) / 2`: blocks that are
/// symmetric in exact arithmetic (`∫ w b bᵀ`) come out of their sums asymmetric by rounding,
/// and the conjugate gradients want an exactly symmetric operator.
pub(super) fn symmetrise(blocks: &mut [f64], l: usize) {
    blocks.par_chunks_mut(NODE_CHUNK * l * l).for_each(|chunk| {
        for block in chunk.chunks_mut(l * l) {
            for i in 0..l {
                for j in i + 1..l {
                    let mean = 0.5 * (block[i * l + j] + block[j * l + i]);
                    block[i * l + j] = mean;
                    block[j * l + i] = mean;
                }
            }
        }
    });
}

/// `buffer` as `len` zeros, reusing its allocation.
pub(super) fn zeroed(buffer: &mut Vec<f64>, len: usize) {
    buffer.clear();
    buffer.resize(len, 0.0);
}

/// Global index of corner `k` (bit a: one step up along axis a) of the voxel-centre cell whose
/// lowest voxel is `lower`.
pub(super) fn corner_voxel(lower: [usize; 3], k: usize, voxels: [usize; 3]) -> usize {
    let at = [0, 1, 2].map(|a| lower[a] + (k >> a & 1));
    at[0] + voxels[0] * (at[1] + voxels[1] * at[2])
}

/// Adds one voxel-centre cell's corner-pair blocks `a` (pairs `k ≤ k'` in order, `size`
/// values each) to per-voxel neighbour blocks `blocks` stored once per pair ([`pair_block`]).
/// The blocks are symmetric in exact arithmetic (`∫ w b bᵀ`, `∫ w c cᵀ`, or columns), so the
/// block of `(k, k')` serves as that of `(k', k)` without being transposed; [`symmetrise`]
/// removes the rounding.
pub(super) fn add_pair_blocks(
    blocks: &mut [f64],
    size: usize,
    lower: [usize; 3],
    a: &[f64],
    voxels: [usize; 3],
) {
    let delta = |from: usize, to: usize| -> usize {
        (0..3)
            .map(|axis| {
                ((to >> axis & 1) as isize - (from >> axis & 1) as isize + 1) as usize
                    * [1, 3, 9][axis]
            })
            .sum()
    };
    let mut pair = 0;
    for k in 0..8 {
        let vk = corner_voxel(lower, k, voxels);
        for k2 in k..8 {
            let src = &a[pair * size..(pair + 1) * size];
            pair += 1;
            let at = pair_block(vk, corner_voxel(lower, k2, voxels), delta(k, k2)) * size;
            for (o, &x) in blocks[at..at + size].iter_mut().zip(src) {
                *o += x;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each pair of neighbouring voxels has one stored block, the same seen from either voxel,
    /// and no two pairs share one.
    #[test]
    pub(super) fn pair_blocks_are_stored_once_per_pair() {
        let voxels = [3, 4, 2];
        let count = voxels.iter().product();
        let mut owner = vec![None; count * STORED_BLOCKS];
        // Per axis a voxel has 2 or 3 neighbours in its 3-block (itself included): 7, 10 and 4
        // summed over the axes' positions.
        let pairs: usize = (0..count).map(|v| neighbours(v, voxels).count()).sum();
        assert_eq!(pairs, 7 * 10 * 4);
        for v in 0..count {
            for (nbr, u) in neighbours(v, voxels) {
                let slot = pair_block(v, u, nbr);
                assert_eq!(slot, pair_block(u, v, 26 - nbr));
                let pair = (v.min(u), v.max(u));
                assert_eq!(*owner[slot].get_or_insert(pair), pair);
            }
        }
        assert_eq!(pair_block(5, 5, SELF_BLOCK), 5 * STORED_BLOCKS);
    }

    /// Every voxel once; each column a `COLUMN × COLUMN` (or smaller, at the edges) footprint,
    /// walked plane by plane.
    #[test]
    pub(super) fn column_order_walks_every_voxel_once() {
        let voxels = [37, 18, 3];
        let (order, starts) = column_order(voxels);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..37 * 18 * 3).collect::<Vec<_>>());
        assert_eq!(starts.len(), 3 * 2 + 1);
        assert_eq!(*starts.last().unwrap(), order.len());
        for range in starts.windows(2) {
            let column = &order[range[0]..range[1]];
            let z = |v: usize| v / (37 * 18);
            assert!(column.windows(2).all(|w| z(w[0]) <= z(w[1])));
            let xs: Vec<usize> = column.iter().map(|v| v % 37).collect();
            assert!(xs.iter().max().unwrap() - xs.iter().min().unwrap() < COLUMN);
        }
    }

    #[test]
    pub(super) fn symmetrise_averages_each_block_with_its_transpose() {
        let mut blocks = vec![1.0, 2.0, 4.0, 3.0, 0.0, -1.0, 1.0, 5.0];
        symmetrise(&mut blocks, 2);
        assert_eq!(blocks, vec![1.0, 3.0, 3.0, 3.0, 0.0, 0.0, 0.0, 5.0]);
    }
}
