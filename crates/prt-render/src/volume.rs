//! The box of a voxel grid from the box of its voxel centres.

use glam::Vec3;
use prt_core::Aabb;

/// The box of a `dims` voxel grid whose voxel centres span `centres` (where a hat grid with one
/// node per voxel puts its nodes, e.g. an MBD container's coefficient kernels): `centres`
/// widened by half a voxel on each side. An axis of one voxel gets the edge length of the
/// largest other voxel edge (or 1 when every axis has one voxel).
pub fn grid_bounds(centres: Aabb, dims: [usize; 3]) -> Aabb {
    let size = centres.size();
    let edge: [Option<f32>; 3] =
        std::array::from_fn(|k| (dims[k] >= 2).then(|| size[k] / (dims[k] - 1) as f32));
    let fallback = edge.iter().flatten().copied().fold(0.0f32, f32::max);
    let fallback = if fallback > 0.0 { fallback } else { 1.0 };
    let half = Vec3::from_array(edge.map(|e| 0.5 * e.unwrap_or(fallback)));
    Aabb {
        min: centres.min - half,
        max: centres.max + half,
    }
}
