//! The views a scene offers: its glTF cameras, then two automatic ones.

use glam::Vec3;
use prt_trace::camera::PinholeView;
use prt_trace::{RayTracer, Scene};

/// Vertical field of view of the automatic views (radians): 40°.
const AUTO_FOV_DEGREES: f32 = 40.0;
/// Vertical field of view of the automatic inside view: 60°.
const INSIDE_FOV_DEGREES: f32 = 60.0;
/// Where the inside view's eye may stand: fractions of the long horizontal extent in from its
/// +end, tried in order.
const INSIDE_DEPTHS: [f32; 9] = [0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.45];
/// Directions cast from a candidate eye to tell open space from a sealed pocket.
const OPENNESS_DIRECTIONS: usize = 256;
/// Share of those directions that must leave the scene unoccluded for an eye to count as open.
const OPEN_SHARE: f32 = 0.01;

/// A view with a name to list it by.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedView {
    /// The camera's name in the file, `camera K` for an unnamed one, or the automatic view's
    /// name (`front`, `inside`).
    pub name: String,
    /// The view.
    pub view: PinholeView,
}

/// Every view of `scene`, in the order `--camera N` counts them: the scene's glTF cameras (in
/// file order), then two automatic views of its bounds (none for a scene without triangles):
///
/// * `front`: [`PinholeView::framing`] with a 40° vertical field of view, looking along -Z at
///   the box's centre from far enough in +Z that its x-y extent fills the view (the Cornell
///   box's classic view through its open side);
/// * `inside`: from inside the box, 5 % of the long horizontal extent in from its +end (+X or
///   +Z, whichever axis is longer), at 40 % of the height, looking back along that axis and
///   10° down, 60° vertical field of view (down the nave of an atrium like Sponza's). An eye in
///   a sealed pocket (fewer than 1 % of 256 directions leave the scene) would show only light
///   leaking through the geometry, so the eye moves in by 5 % steps, up to 45 %, to the first
///   open point; a scene sealed everywhere keeps the 5 % eye.
pub fn views(scene: &Scene) -> Vec<NamedView> {
    let mut out: Vec<NamedView> = scene
        .cameras()
        .iter()
        .enumerate()
        .map(|(k, c)| NamedView {
            name: c.name.clone().unwrap_or_else(|| format!("camera {k}")),
            view: PinholeView::from_camera(c),
        })
        .collect();
    if let Some(bounds) = scene.bounds() {
        out.push(NamedView {
            name: "front".into(),
            view: PinholeView::framing(&bounds, AUTO_FOV_DEGREES.to_radians()),
        });
        let size = bounds.size();
        let along = if size.x > size.z { Vec3::X } else { Vec3::Z };
        let centre = bounds.centre();
        let length = size.dot(along);
        let eye_at = |depth: f32| {
            let mut eye = centre + along * ((0.5 - depth) * length);
            eye.y = bounds.min.y + 0.4 * size.y;
            eye
        };
        let tracer = RayTracer::new(scene.triangles());
        let reach = 2.0 * size.length();
        let eye = INSIDE_DEPTHS
            .iter()
            .map(|&depth| eye_at(depth))
            .find(|&eye| open_share(&tracer, eye, reach) >= OPEN_SHARE)
            .unwrap_or_else(|| eye_at(INSIDE_DEPTHS[0]));
        let pitch = 10f32.to_radians();
        let forward = (-along * pitch.cos() - Vec3::Y * pitch.sin()).normalize();
        let right = forward.cross(Vec3::Y).normalize();
        out.push(NamedView {
            name: "inside".into(),
            view: PinholeView {
                position: eye,
                forward,
                up: right.cross(forward),
                yfov: INSIDE_FOV_DEGREES.to_radians(),
            },
        });
    }
    out
}

/// Share of [`OPENNESS_DIRECTIONS`] directions (a Fibonacci sphere) from `eye` that hit nothing
/// within `reach`.
fn open_share(tracer: &RayTracer, eye: Vec3, reach: f32) -> f32 {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let rays: Vec<(Vec3, Vec3)> = (0..OPENNESS_DIRECTIONS)
        .map(|k| {
            let z = 1.0 - (2 * k + 1) as f32 / OPENNESS_DIRECTIONS as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * k as f32;
            (eye, Vec3::new(r * phi.cos(), r * phi.sin(), z))
        })
        .collect();
    let escaped = tracer
        .occluded_batch(&rays, 0.0, reach)
        .iter()
        .filter(|&&hit| !hit)
        .count();
    escaped as f32 / OPENNESS_DIRECTIONS as f32
}
