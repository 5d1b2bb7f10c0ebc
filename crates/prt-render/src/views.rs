//! The views a scene offers: its glTF cameras, then two automatic ones.

use glam::Vec3;
use prt_trace::Scene;
use prt_trace::camera::PinholeView;

/// Vertical field of view of the automatic views (radians): 40°.
const AUTO_FOV_DEGREES: f32 = 40.0;
/// Vertical field of view of the automatic inside view: 60°.
const INSIDE_FOV_DEGREES: f32 = 60.0;

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
///   10° down, 60° vertical field of view (down the nave of an atrium like Sponza's).
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
        let mut eye = centre + along * (0.45 * length);
        eye.y = bounds.min.y + 0.4 * size.y;
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
