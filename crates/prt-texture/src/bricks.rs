//! The brick layout of a container array: the live part of a node grid cut into bricks of
//! `B` cells, each stored with a one-node apron in a brick atlas, plus an indirection grid of one
//! texel per brick (docs/formats.md, "Brick layout").

use serde::{Deserialize, Serialize};

use crate::TextureError;
use crate::limits::checked_product;

/// Cells per brick edge [`crate::container::Container`] uses unless told otherwise (Unreal's
/// volumetric lightmaps use 4 cells with a one-texel border; so does this layout).
pub const DEFAULT_BRICK_SIZE: u32 = 4;
/// Largest brick edge accepted, in cells.
pub const MAX_BRICK_SIZE: u32 = 64;
/// Largest number of bricks along an axis of the atlas: the indirection stores atlas brick
/// coordinates in 8 bits.
pub const MAX_ATLAS_BRICKS: u32 = 256;

/// Where a brick-layout array's bricks are: the manifest's `bricks` entry.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bricks {
    /// Cells per brick edge B: brick `b` holds nodes `b·B ..= b·B + B` along each axis
    /// (`(B+1)³` texels, the last layer an apron duplicating the next brick's first nodes, so
    /// trilinear filtering inside a brick never needs a neighbour).
    pub size: u32,
    /// Bricks along x, y, z: `max(1, ⌈(dims − 1) / B⌉)`.
    pub grid: [u32; 3],
    /// Bricks stored in the atlas (the live ones).
    pub live: u64,
    /// Bricks along x, y, z of the atlas of one channel group; the groups are stacked along z.
    pub atlas: [u32; 3],
    /// The indirection texture: `<name>.bricks.ktx2`.
    pub indirection: String,
    /// Size of the indirection file in bytes.
    pub indirection_bytes: u64,
}

/// What a writer asks for: the brick size and which nodes must be stored exactly.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrickRequest {
    /// Cells per brick edge (1 ..= [`MAX_BRICK_SIZE`]).
    pub size: u32,
    /// Per node of the array (x fastest): whether it must be stored. A brick is stored when any
    /// of its `(B+1)³` nodes is live; the nodes of the other bricks read back as 0.
    pub live_nodes: Vec<bool>,
}

impl BrickRequest {
    /// A request for bricks of [`DEFAULT_BRICK_SIZE`] cells.
    pub fn new(live_nodes: Vec<bool>) -> Self {
        BrickRequest {
            size: DEFAULT_BRICK_SIZE,
            live_nodes,
        }
    }
}

/// Bricks along each axis of a grid of `dims` nodes cut in bricks of `size` cells.
pub fn brick_grid(dims: [u32; 3], size: u32) -> [u32; 3] {
    dims.map(|n| n.saturating_sub(1).div_ceil(size.max(1)).max(1))
}

/// The brick holding node `i` along an axis (the last brick also holds the last node) and the
/// node's position inside it, `0 ..= size`.
pub(crate) fn brick_of(i: u32, size: u32, bricks: u32) -> (u32, u32) {
    let b = (i / size).min(bricks - 1);
    (b, i - b * size)
}

/// Which bricks hold a live node among their `(B+1)³` nodes, brick index x fastest.
pub fn live_bricks(
    dims: [u32; 3],
    size: u32,
    live_nodes: &[bool],
) -> Result<Vec<bool>, TextureError> {
    Ok(LiveBricks::of_nodes(dims, size, live_nodes)?.live)
}

/// Which bricks of a node grid hold a live node, marked a node at a time: what a streamed
/// writer needs of the live nodes ([`live_bricks`] of them all), in one flag per brick.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveBricks {
    dims: [u32; 3],
    size: u32,
    grid: [u32; 3],
    live: Vec<bool>,
}

impl LiveBricks {
    /// No live brick yet, of a grid of `dims` nodes cut in bricks of `size` cells.
    ///
    /// # Errors
    /// A size outside `1..=MAX_BRICK_SIZE`; a grid whose node count overflows.
    pub fn new(dims: [u32; 3], size: u32) -> Result<LiveBricks, TextureError> {
        checked_product("brick nodes", &dims.map(u64::from))?;
        if size == 0 || size > MAX_BRICK_SIZE {
            return Err(TextureError::invalid(
                "brick size",
                format!("{size} is not in 1..={MAX_BRICK_SIZE}"),
            ));
        }
        let grid = brick_grid(dims, size);
        let bricks = checked_product("bricks", &grid.map(u64::from))?;
        Ok(LiveBricks {
            dims,
            size,
            grid,
            live: vec![false; bricks as usize],
        })
    }

    /// The bricks of `live_nodes` (per node of `dims`, x fastest) cut in bricks of `size`.
    ///
    /// # Errors
    /// As [`LiveBricks::new`]; flags of another length than the grid's nodes.
    pub fn of_nodes(
        dims: [u32; 3],
        size: u32,
        live_nodes: &[bool],
    ) -> Result<LiveBricks, TextureError> {
        let nodes = checked_product("brick nodes", &dims.map(u64::from))?;
        if live_nodes.len() as u64 != nodes {
            return Err(TextureError::LengthMismatch {
                what: "live nodes",
                expected: nodes as usize,
                got: live_nodes.len(),
            });
        }
        let mut live = LiveBricks::new(dims, size)?;
        let [nx, ny, _] = dims.map(|d| d as usize);
        for (n, _) in live_nodes.iter().enumerate().filter(|(_, l)| **l) {
            live.mark([n % nx, n / nx % ny, n / (nx * ny)].map(|i| i as u32))?;
        }
        Ok(live)
    }

    /// Marks the bricks holding `node`: the brick that owns it and, on a brick border, the one
    /// before it (whose apron it is).
    ///
    /// # Errors
    /// A node outside the grid.
    pub fn mark(&mut self, node: [u32; 3]) -> Result<(), TextureError> {
        if (0..3).any(|a| node[a] >= self.dims[a]) {
            return Err(TextureError::invalid(
                "live node",
                format!("{node:?} outside a grid of {:?} nodes", self.dims),
            ));
        }
        let span = |a: usize| {
            let (b, q) = brick_of(node[a], self.size, self.grid[a]);
            let first = if q == 0 && b > 0 { b - 1 } else { b };
            first as usize..=b as usize
        };
        let [gx, gy, _] = self.grid.map(|g| g as usize);
        for bz in span(2) {
            for by in span(1) {
                for bx in span(0) {
                    self.live[bx + gx * (by + gy * bz)] = true;
                }
            }
        }
        Ok(())
    }

    /// The grid's nodes along x, y, z.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Cells per brick edge.
    pub fn size(&self) -> u32 {
        self.size
    }

    /// Per brick (x fastest): whether it holds a live node.
    pub fn live(&self) -> &[bool] {
        &self.live
    }

    /// The live bricks.
    pub fn count(&self) -> u64 {
        self.live.iter().filter(|&&l| l).count() as u64
    }
}

/// The atlas arrangement of `live` bricks: close to a cube, x first, then y, then z, at most
/// [`MAX_ATLAS_BRICKS`] along each axis.
pub fn brick_atlas(live: u64) -> Result<[u32; 3], TextureError> {
    let n = live.max(1) as f64;
    let ax = n.cbrt().ceil().clamp(1.0, f64::from(MAX_ATLAS_BRICKS));
    let ay = (n / ax)
        .sqrt()
        .ceil()
        .clamp(1.0, f64::from(MAX_ATLAS_BRICKS));
    let az = (n / (ax * ay)).ceil().max(1.0);
    if az > f64::from(MAX_ATLAS_BRICKS) {
        return Err(TextureError::TooLarge {
            what: "live bricks",
            value: live,
            limit: u64::from(MAX_ATLAS_BRICKS).pow(3),
        });
    }
    Ok([ax as u32, ay as u32, az as u32])
}

/// Atlas slot `s` (0-based, x fastest) as a brick coordinate of an atlas of `atlas` bricks.
pub(crate) fn slot_coordinate(s: usize, atlas: [u32; 3]) -> [usize; 3] {
    let [ax, ay, _] = atlas.map(|a| a as usize);
    [s % ax, s / ax % ay, s / (ax * ay)]
}

/// Texels per atlas axis for `groups` channel groups: `atlas · (B+1)`, z times `groups`.
pub(crate) fn atlas_texels(bricks: &Bricks, groups: usize) -> Result<[u64; 3], TextureError> {
    let side = u64::from(bricks.size) + 1;
    let [ax, ay, az] = bricks.atlas.map(u64::from);
    let z = checked_product("brick atlas depth", &[az, side, groups as u64])?;
    Ok([ax * side, ay * side, z])
}
