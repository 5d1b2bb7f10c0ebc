//! The automatic views: where the inside view's eye stands.

use glam::Vec3;
use prt_render::views;
use prt_trace::Scene;
use prt_trace::scene::Material;

/// The two triangles of an axis-aligned quad with corners `a` and `b` lying in the plane where
/// `axis` is constant.
fn quad(a: Vec3, b: Vec3, axis: usize) -> [[Vec3; 3]; 2] {
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let corner = |du: bool, dv: bool| {
        let mut p = a;
        if du {
            p[u] = b[u];
        }
        if dv {
            p[v] = b[v];
        }
        p
    };
    let (p00, p10, p11, p01) = (
        corner(false, false),
        corner(true, false),
        corner(true, true),
        corner(false, true),
    );
    [[p00, p10, p11], [p00, p11, p01]]
}

/// The six faces of the box from `min` to `max`.
fn closed_box(min: Vec3, max: Vec3) -> Vec<[Vec3; 3]> {
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for side in [min[axis], max[axis]] {
            let (mut a, mut b) = (min, max);
            a[axis] = side;
            b[axis] = side;
            triangles.extend(quad(a, b, axis));
        }
    }
    triangles
}

fn scene(triangles: Vec<[Vec3; 3]>) -> Scene {
    let ids = vec![0; triangles.len()];
    Scene::from_triangles(
        triangles,
        ids,
        vec![Material::diffuse("grey", Vec3::splat(0.5))],
    )
    .expect("scene")
}

fn inside_eye(scene: &Scene) -> Vec3 {
    let all = views(scene);
    let inside = all
        .iter()
        .find(|v| v.name == "inside")
        .expect("inside view");
    inside.view.position
}

/// A floor 10 long in x and 2 wide in z, open to the sky, with a sealed 1.2-long room at its
/// +x end: the 5 % and 10 % eyes (x = 9.5, 9.0) stand in the room, the 15 % one (x = 8.5) above
/// the open floor.
fn floor_with_sealed_end() -> Vec<[Vec3; 3]> {
    let mut triangles = quad(Vec3::ZERO, Vec3::new(10.0, 0.0, 2.0), 1).to_vec();
    triangles.extend(closed_box(
        Vec3::new(8.8, 0.0, 0.0),
        Vec3::new(10.0, 2.0, 2.0),
    ));
    triangles
}

#[test]
fn the_inside_eye_leaves_a_sealed_pocket_for_the_first_open_point() {
    let eye = inside_eye(&scene(floor_with_sealed_end()));
    assert!((eye.x - 8.5).abs() < 1e-4, "eye {eye}");
    assert!(
        (eye.y - 0.8).abs() < 1e-4 && (eye.z - 1.0).abs() < 1e-4,
        "eye {eye}"
    );
}

#[test]
fn an_open_scene_keeps_the_eye_five_percent_in() {
    let eye = inside_eye(&scene(
        quad(Vec3::ZERO, Vec3::new(10.0, 0.0, 2.0), 1).to_vec(),
    ));
    // A flat floor has no height: the eye stands on it, 0.5 in from the +x end.
    assert!((eye.x - 9.5).abs() < 1e-4, "eye {eye}");
    let cornell = Scene::cornell_box();
    let bounds = cornell.bounds().expect("bounds");
    let size = bounds.size();
    let eye = inside_eye(&cornell);
    let along_x = size.x > size.z;
    let expected = if along_x {
        bounds.max.x - 0.05 * size.x
    } else {
        bounds.max.z - 0.05 * size.z
    };
    let got = if along_x { eye.x } else { eye.z };
    assert!(
        (got - expected).abs() < 1e-4 * size.max_element(),
        "eye {eye}"
    );
}

#[test]
fn a_scene_sealed_everywhere_keeps_the_eye_five_percent_in() {
    let mut triangles = floor_with_sealed_end();
    triangles.extend(closed_box(
        Vec3::new(-1.0, -1.0, -1.0),
        Vec3::new(11.0, 3.0, 3.0),
    ));
    let eye = inside_eye(&scene(triangles));
    // The outer shell's bounds: x from -1 to 11, so 5 % in is 11 - 0.6.
    assert!((eye.x - 10.4).abs() < 1e-4, "eye {eye}");
}
