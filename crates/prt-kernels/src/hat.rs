use glam::Vec3;
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};

use crate::KernelError;

/// Tensor-product linear hat kernels on a regular grid of nodes: trilinear interpolation
/// weights, seen as a kernel family.
///
/// Node `(i, j, k)` sits at `domain.min + (i, j, k) * size / (nodes - 1)`; its flat index is
/// `i + nx * (j + ny * k)`. Kernel `(i, j, k)` is the product of 1D hats, each 1 on its node and
/// falling linearly to 0 on the neighbouring nodes, so the family is a partition of unity and
/// reproduces affine functions exactly.
///
/// * **Single-node axes.** An axis with one node is constant along it (its hat is 1 everywhere
///   and its node sits at the domain's centre on that axis). This is how 1D and 2D grids are
///   expressed: [`HatGrid::line_x`] is `[n, 1, 1]`, [`HatGrid::plane_xz`] is `[nx, 1, nz]`.
///   With `d` axes of two or more nodes, at most `2^d` kernels are non-zero at a point.
/// * **Outside the domain** a point is clamped to the box, so the weights there are those of the
///   nearest point of the box (constant extrapolation).
/// * **Cells.** The grid cell holding `x` (the box between `2^d` neighbouring nodes) is the
///   [`SpatialKernels::support_cell`]: every point of a cell uses the same corner nodes. A point
///   on a shared face belongs to the cell on its lower side, except on the domain's upper face.
///
/// ```
/// use glam::Vec3;
/// use prt_core::{Aabb, SpatialKernels};
/// use prt_kernels::HatGrid;
///
/// let grid = HatGrid::new([3, 3, 3], Aabb::UNIT).unwrap();
/// let local = grid.eval_local(Vec3::new(0.25, 0.5, 0.75)).unwrap();
/// assert_eq!(local.cell(), [0, 1, 1]);
/// let sum: f32 = local.weights().iter().sum();
/// assert!((sum - 1.0).abs() < 1e-6);
/// assert_eq!(grid.max_support(), 8);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct HatGrid {
    nodes: [usize; 3],
    domain: Aabb,
    /// `domain.min` in f64, so that `x - min` is exact.
    origin: [f64; 3],
    /// Node intervals per unit length, `(n - 1) / size` (0 on single-node axes, which makes the
    /// cell lookup branch-free: their coordinate is always 0).
    scale: [f64; 3],
    /// `n - 1` per axis: the largest cell coordinate, as f64.
    last_node: [f64; 3],
    /// The largest cell index per axis (`n - 2`, or 0 on single-node axes).
    last_cell: [usize; 3],
    /// Flat-index strides of the three axes.
    strides: [usize; 3],
    /// Axes with at least two nodes, in increasing order; the first `active_len` are valid.
    active: [usize; 3],
    active_len: usize,
    /// Flat-index offsets of a cell's corners from its lowest node (bit `b` of the corner number
    /// steps along the `b`-th active axis).
    corner_offsets: [u32; 8],
    len: usize,
}

/// The hat weights at one point, without allocation: the grid cell holding the point and the
/// weights of its `2^d` corner nodes (see [`HatGrid::cell_corners`] for their order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HatLocal {
    cell: [usize; 3],
    indices: [u32; 8],
    weights: [f32; 8],
    len: usize,
}

impl HatLocal {
    /// The cell coordinates `(cx, cy, cz)` (0 on single-node axes).
    pub fn cell(&self) -> [usize; 3] {
        self.cell
    }

    /// Flat node indices of the cell's corners.
    pub fn indices(&self) -> &[u32] {
        &self.indices[..self.len]
    }

    /// Weights of the corners, parallel to [`HatLocal::indices`]: non-negative, summing to 1
    /// (up to f32 rounding). Corners may have weight exactly 0 (a point on a node or a face).
    pub fn weights(&self) -> &[f32] {
        &self.weights[..self.len]
    }
}

/// The corner nodes of one grid cell, in the order used by [`HatLocal`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HatCorners {
    indices: [u32; 8],
    len: usize,
}

impl HatCorners {
    /// Flat node indices of the corners.
    pub fn indices(&self) -> &[u32] {
        &self.indices[..self.len]
    }
}

impl HatGrid {
    /// A hat grid with `nodes` nodes per axis over `domain`.
    ///
    /// Errors: an axis with 0 nodes ([`KernelError::NoNodes`]), a domain that is not a finite
    /// box ([`KernelError::InvalidDomain`]), an axis of two or more nodes with zero extent
    /// ([`KernelError::DegenerateAxis`]), more than `u32::MAX` nodes in total
    /// ([`KernelError::TooManyKernels`]). Nothing is allocated, so huge grids are cheap.
    pub fn new(nodes: [usize; 3], domain: Aabb) -> Result<HatGrid, KernelError> {
        if let Some(axis) = (0..3).find(|&k| nodes[k] == 0) {
            return Err(KernelError::NoNodes { axis });
        }
        if !domain.is_valid() {
            return Err(KernelError::InvalidDomain {
                min: domain.min.to_array(),
                max: domain.max.to_array(),
            });
        }
        let len = nodes
            .iter()
            .try_fold(1usize, |acc, &n| acc.checked_mul(n))
            .filter(|&len| len <= u32::MAX as usize)
            .ok_or_else(|| KernelError::TooManyKernels {
                what: format!("{} x {} x {} nodes", nodes[0], nodes[1], nodes[2]),
            })?;
        let mut origin = [0.0; 3];
        let mut scale = [0.0; 3];
        let mut active = [0; 3];
        let mut active_len = 0;
        for k in 0..3 {
            origin[k] = domain.min[k] as f64;
            // The extent in f64: finite even when the f32 difference would overflow.
            let size = domain.max[k] as f64 - domain.min[k] as f64;
            if nodes[k] >= 2 {
                if size <= 0.0 {
                    return Err(KernelError::DegenerateAxis {
                        axis: k,
                        nodes: nodes[k],
                    });
                }
                scale[k] = (nodes[k] - 1) as f64 / size;
                active[active_len] = k;
                active_len += 1;
            }
        }
        let strides = [1, nodes[0], nodes[0] * nodes[1]];
        let mut corner_offsets = [0u32; 8];
        for (corner, offset) in corner_offsets.iter_mut().enumerate().take(1 << active_len) {
            // Each offset is at most the index of the last node, which fits u32 (checked above).
            let flat: usize = (0..active_len)
                .filter(|b| corner >> b & 1 == 1)
                .map(|b| strides[active[b]])
                .sum();
            *offset = flat as u32;
        }
        Ok(HatGrid {
            nodes,
            domain,
            origin,
            scale,
            last_node: nodes.map(|n| (n - 1) as f64),
            last_cell: nodes.map(|n| n.saturating_sub(2)),
            strides,
            active,
            active_len,
            corner_offsets,
            len,
        })
    }

    /// A 1D grid of `n` nodes along x, constant along y and z (`[n, 1, 1]`).
    pub fn line_x(n: usize, domain: Aabb) -> Result<HatGrid, KernelError> {
        HatGrid::new([n, 1, 1], domain)
    }

    /// A 2D grid of `nx × nz` nodes over the ground plane, constant along y (`[nx, 1, nz]`);
    /// node `(i, k)` has flat index `i + nx * k`.
    pub fn plane_xz(nx: usize, nz: usize, domain: Aabb) -> Result<HatGrid, KernelError> {
        HatGrid::new([nx, 1, nz], domain)
    }

    /// Nodes per axis.
    pub fn nodes(&self) -> [usize; 3] {
        self.nodes
    }

    /// Cells per axis: `nodes - 1`, or 1 on single-node axes.
    pub fn cells(&self) -> [usize; 3] {
        self.nodes.map(|n| n.saturating_sub(1).max(1))
    }

    /// Number of axes with two or more nodes (the `d` of `2^d` non-zero kernels).
    pub fn active_axes(&self) -> usize {
        self.active_len
    }

    /// Flat index of node `(i, j, k)`, or `None` if it is outside the grid.
    pub fn node_index(&self, node: [usize; 3]) -> Option<u32> {
        if (0..3).any(|k| node[k] >= self.nodes[k]) {
            return None;
        }
        let flat: usize = (0..3).map(|k| node[k] * self.strides[k]).sum();
        Some(flat as u32)
    }

    /// The node coordinates `(i, j, k)` of flat index `index`, or `None` if out of range.
    pub fn node_coords(&self, index: usize) -> Option<[usize; 3]> {
        if index >= self.len {
            return None;
        }
        let [nx, ny, _] = self.nodes;
        Some([index % nx, index / nx % ny, index / (nx * ny)])
    }

    /// Position of node `(i, j, k)` (the domain's centre along single-node axes), or `None` if
    /// the node is outside the grid.
    pub fn node_position(&self, node: [usize; 3]) -> Option<Vec3> {
        if (0..3).any(|k| node[k] >= self.nodes[k]) {
            return None;
        }
        let mut p = [0.0f32; 3];
        for k in 0..3 {
            let (lo, hi) = (self.domain.min[k] as f64, self.domain.max[k] as f64);
            p[k] = if self.nodes[k] == 1 {
                0.5 * (lo + hi)
            } else {
                lo + (hi - lo) * node[k] as f64 / (self.nodes[k] - 1) as f64
            } as f32;
        }
        Some(Vec3::from_array(p))
    }

    /// Flat index of cell `(cx, cy, cz)` (x fastest), as returned by
    /// [`SpatialKernels::support_cell`]; `None` if the cell is outside the grid.
    pub fn cell_index(&self, cell: [usize; 3]) -> Option<usize> {
        let cells = self.cells();
        if (0..3).any(|k| cell[k] >= cells[k]) {
            return None;
        }
        Some(cell[0] + cells[0] * (cell[1] + cells[1] * cell[2]))
    }

    /// The cell coordinates of flat cell index `index`, or `None` if out of range.
    pub fn cell_coords(&self, index: usize) -> Option<[usize; 3]> {
        let [cx, cy, cz] = self.cells();
        if index >= cx * cy * cz {
            return None;
        }
        Some([index % cx, index / cx % cy, index / (cx * cy)])
    }

    /// The cell holding `x` (clamped to the domain); a non-finite `x` is
    /// [`CoreError::NonFinite`] naming the axis.
    pub fn cell_of(&self, x: Vec3) -> Result<[usize; 3], CoreError> {
        Ok(self.locate(x)?.0)
    }

    /// The `2^d` corner nodes of cell `(cx, cy, cz)`, or `None` if the cell is outside the grid.
    ///
    /// Corner `c` steps one node up along the `b`-th axis that has two or more nodes when bit `b`
    /// of `c` is set; for a full 3D grid bit 0 is x, bit 1 is y and bit 2 is z, the order of
    /// [`prt_core::TrilinearWeights`].
    pub fn cell_corners(&self, cell: [usize; 3]) -> Option<HatCorners> {
        self.cell_index(cell)?;
        let base = self.base_node(cell);
        let mut indices = [0u32; 8];
        let len = 1 << self.active_len;
        for c in 0..len {
            indices[c] = base + self.corner_offsets[c];
        }
        Some(HatCorners { indices, len })
    }

    /// The hat weights at `x` (clamped to the domain): its cell and the weights of the cell's
    /// `2^d` corners, without allocating. A non-finite `x` is [`CoreError::NonFinite`].
    #[inline]
    pub fn eval_local(&self, x: Vec3) -> Result<HatLocal, CoreError> {
        let (cell, t) = self.locate(x)?;
        let base = self.base_node(cell);
        // Per active-axis slot, the weights of its lower and upper node; unused slots are (1, 0),
        // so one fixed 8-corner product (unrolled by the compiler) serves every dimension.
        let mut pair = [[1.0f32, 0.0]; 3];
        for b in 0..self.active_len {
            let tk = t[self.active[b]];
            pair[b] = [1.0 - tk, tk];
        }
        let mut indices = [0u32; 8];
        let mut weights = [0.0f32; 8];
        for c in 0..8 {
            indices[c] = base + self.corner_offsets[c];
            weights[c] = pair[0][c & 1] * pair[1][c >> 1 & 1] * pair[2][c >> 2 & 1];
        }
        let len = 1 << self.active_len;
        Ok(HatLocal {
            cell,
            indices,
            weights,
            len,
        })
    }

    /// Cell coordinates and the fractional position inside the cell per axis (0 on
    /// single-node axes).
    #[inline]
    fn locate(&self, x: Vec3) -> Result<([usize; 3], [f32; 3]), CoreError> {
        if !x.is_finite() {
            let index = (0..3).find(|&k| !x[k].is_finite()).unwrap_or(0);
            return Err(CoreError::NonFinite {
                what: "query point",
                index,
            });
        }
        let mut cell = [0usize; 3];
        let mut t = [0.0f32; 3];
        // All three axes without branching: a single-node axis has scale 0 and lands on cell 0.
        for k in 0..3 {
            // f64 keeps the fraction accurate on grids with millions of nodes per axis.
            let u = ((x[k] as f64 - self.origin[k]) * self.scale[k]).clamp(0.0, self.last_node[k]);
            // u >= 0, so truncation is floor.
            let c = (u as usize).min(self.last_cell[k]);
            cell[k] = c;
            t[k] = (u - c as f64) as f32;
        }
        Ok((cell, t))
    }

    #[inline]
    fn base_node(&self, cell: [usize; 3]) -> u32 {
        // The lowest corner is a node of the grid, so the sum fits u32.
        (cell[0] * self.strides[0] + cell[1] * self.strides[1] + cell[2] * self.strides[2]) as u32
    }
}

impl SpatialKernels for HatGrid {
    fn len(&self) -> usize {
        self.len
    }

    fn max_support(&self) -> usize {
        1 << self.active_len
    }

    fn domain(&self) -> Aabb {
        self.domain
    }

    /// Writes the corners of `x`'s cell whose weight is non-zero (a point on a node writes one
    /// kernel); points outside the domain are clamped to it.
    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        out.clear();
        let local = self.eval_local(x)?;
        for (&i, &w) in local.indices().iter().zip(local.weights()) {
            if w > 0.0 {
                out.push(i, w);
            }
        }
        Ok(())
    }

    /// The flat index of the cell holding `x` (clamped), `None` for a non-finite `x`.
    fn support_cell(&self, x: Vec3) -> Option<usize> {
        let cell = self.cell_of(x).ok()?;
        self.cell_index(cell)
    }

    fn num_support_cells(&self) -> usize {
        self.cells().iter().product()
    }

    fn centre(&self, i: usize) -> Option<Vec3> {
        self.node_position(self.node_coords(i)?)
    }
}
