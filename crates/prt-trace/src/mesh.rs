//! The scene mesh file (`scene.mesh`): a scene's triangles, materials and cameras in a small
//! little-endian binary format that `prt render` and a browser can both read (docs/formats.md); `prt bake` writes it beside the
//! container.

use std::collections::HashMap;
use std::path::Path;

use glam::{Mat4, Vec3};
use prt_texture::{Limits, TextureError, write_atomic};

use crate::scene::{Camera, Material};
use crate::{Scene, TraceError};

/// The first eight bytes of a scene mesh file.
pub const MESH_MAGIC: [u8; 8] = *b"PRTMESH\0";
/// The format version this crate writes and reads.
pub const MESH_VERSION: u32 = 1;
/// Bytes of the header: magic, version, four counts, a reserved word.
const HEADER_BYTES: usize = 32;
/// Material flag: both faces reflect (and emit).
const DOUBLE_SIDED: u32 = 1;
/// Name length of a camera without a name.
const NO_NAME: u32 = u32::MAX;

/// An error of writing or reading a scene mesh file ([`read_mesh`], [`decode_mesh`], [`write_mesh`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// Reading the file failed.
    #[error("cannot read the mesh file: {0}")]
    Io(#[from] std::io::Error),
    /// Writing the file failed.
    #[error("cannot write the mesh file: {0}")]
    Write(#[from] TextureError),
    /// The file does not start with the mesh magic.
    #[error("not a prt scene mesh (bad magic)")]
    BadMagic,
    /// A version this reader does not know.
    #[error("scene mesh version {0} is not supported (this reader knows version 1)")]
    UnsupportedVersion(u32),
    /// A size above the reader's limits.
    #[error("{what} is {value}, above the limit {limit}")]
    TooLarge {
        /// What was too large.
        what: &'static str,
        /// Its value.
        value: u64,
        /// The limit.
        limit: u64,
    },
    /// The file ends inside `what`.
    #[error("the file ends inside {what}")]
    Truncated {
        /// The section being read.
        what: &'static str,
    },
    /// Bytes after the last section.
    #[error("{0} bytes after the last section")]
    TrailingBytes(usize),
    /// A NaN or infinite value.
    #[error("non-finite value in {what} {index}")]
    NonFinite {
        /// The section.
        what: &'static str,
        /// Index of the record in it.
        index: usize,
    },
    /// An index that points outside its table.
    #[error("{what} {index} refers to entry {value} of {len}")]
    OutOfRange {
        /// What holds the index.
        what: &'static str,
        /// Which record.
        index: usize,
        /// The index found.
        value: u64,
        /// The table's length.
        len: usize,
    },
    /// A triangle whose vertices disagree on the material.
    #[error("triangle {0} has vertices of different materials")]
    MixedMaterials(usize),
    /// A name that is not UTF-8.
    #[error("the name of {what} {index} is not UTF-8")]
    BadName {
        /// Material or camera.
        what: &'static str,
        /// Which one.
        index: usize,
    },
    /// A value the format does not allow (flag bits, a non-positive field of view, ...).
    #[error("invalid {what} {index}: {why}")]
    Invalid {
        /// The section.
        what: &'static str,
        /// Which record.
        index: usize,
        /// Why.
        why: String,
    },
    /// The scene cannot be written in this format, or rebuilt from the file.
    #[error(transparent)]
    Scene(#[from] TraceError),
}

/// Encodes `scene` as a scene mesh: vertices shared by triangles that agree on position, face
/// normal and material (so a flat-shaded renderer can draw it indexed), one material index per
/// vertex, the materials and the cameras. Lights are not stored.
///
/// Errors: more than `u32::MAX` vertices, triangles, materials or cameras, or a name longer
/// than `u32::MAX - 1` bytes ([`MeshError::TooLarge`]).
pub fn encode_mesh(scene: &Scene) -> Result<Vec<u8>, MeshError> {
    let mut positions: Vec<Vec3> = Vec::new();
    let mut normals: Vec<Vec3> = Vec::new();
    let mut vertex_materials: Vec<u32> = Vec::new();
    let mut indices: Vec<u32> = Vec::with_capacity(3 * scene.triangles().len());
    let mut seen: HashMap<([u32; 3], [u32; 3], u32), u32> = HashMap::new();
    for (t, &m) in scene.triangles().iter().zip(scene.material_ids()) {
        let normal = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
        for &p in t {
            let key = (
                p.to_array().map(f32::to_bits),
                normal.to_array().map(f32::to_bits),
                m,
            );
            let index = *seen.entry(key).or_insert_with(|| {
                positions.push(p);
                normals.push(normal);
                vertex_materials.push(m);
                (positions.len() - 1) as u32
            });
            indices.push(index);
        }
    }
    let count = |what: &'static str, n: usize| {
        u32::try_from(n).map_err(|_| MeshError::TooLarge {
            what,
            value: n as u64,
            limit: u64::from(u32::MAX),
        })
    };
    let mut out = Vec::with_capacity(HEADER_BYTES + 28 * positions.len() + 12 * indices.len());
    out.extend_from_slice(&MESH_MAGIC);
    for word in [
        MESH_VERSION,
        count("vertex count", positions.len())?,
        count("triangle count", scene.triangles().len())?,
        count("material count", scene.materials().len())?,
        count("camera count", scene.cameras().len())?,
        0,
    ] {
        out.extend_from_slice(&word.to_le_bytes());
    }
    let floats = |out: &mut Vec<u8>, values: &[f32]| {
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
    };
    for p in &positions {
        floats(&mut out, &p.to_array());
    }
    for n in &normals {
        floats(&mut out, &n.to_array());
    }
    for word in vertex_materials.iter().chain(&indices) {
        out.extend_from_slice(&word.to_le_bytes());
    }
    for m in scene.materials() {
        floats(&mut out, &m.albedo.to_array());
        floats(&mut out, &m.emissive.to_array());
        let flags = if m.double_sided { DOUBLE_SIDED } else { 0 };
        out.extend_from_slice(&flags.to_le_bytes());
        push_name(&mut out, Some(&m.name))?;
    }
    for c in scene.cameras() {
        floats(&mut out, &c.to_world.to_cols_array());
        floats(&mut out, &[c.yfov, c.aspect_ratio.unwrap_or(0.0), c.znear]);
        push_name(&mut out, c.name.as_deref())?;
    }
    Ok(out)
}

/// A name: its byte length (or [`NO_NAME`]), the UTF-8 bytes, zeros up to a multiple of 4.
fn push_name(out: &mut Vec<u8>, name: Option<&str>) -> Result<(), MeshError> {
    let Some(name) = name else {
        out.extend_from_slice(&NO_NAME.to_le_bytes());
        return Ok(());
    };
    let len = u32::try_from(name.len())
        .ok()
        .filter(|&n| n != NO_NAME)
        .ok_or(MeshError::TooLarge {
            what: "name length",
            value: name.len() as u64,
            limit: u64::from(NO_NAME - 1),
        })?;
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(name.as_bytes());
    out.resize(out.len().next_multiple_of(4), 0);
    Ok(())
}

/// Writes `scene` to `path` as a scene mesh ([`encode_mesh`]), atomically.
pub fn write_mesh(path: &Path, scene: &Scene) -> Result<(), MeshError> {
    write_atomic(path, &encode_mesh(scene)?)?;
    Ok(())
}

/// Reads a scene mesh file, refusing one larger than `limits.max_bytes` before reading it.
pub fn read_mesh(path: &Path, limits: &Limits) -> Result<Scene, MeshError> {
    let len = std::fs::metadata(path)?.len();
    if len > limits.max_bytes {
        return Err(MeshError::TooLarge {
            what: "file size",
            value: len,
            limit: limits.max_bytes,
        });
    }
    decode_mesh(&std::fs::read(path)?, limits)
}

/// Little-endian words from a byte slice, each read checked against its end.
struct Words<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Words<'_> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&[u8], MeshError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&end| end <= self.bytes.len())
            .ok_or(MeshError::Truncated { what })?;
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, MeshError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn f32s<const N: usize>(&mut self, what: &'static str) -> Result<[f32; N], MeshError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = f32::from_bits(self.u32(what)?);
        }
        Ok(out)
    }

    /// Checks that `count` records of `bytes` each fit in what is left, before allocating.
    fn fits(&self, count: u32, bytes: usize, what: &'static str) -> Result<usize, MeshError> {
        let need = u64::from(count) * bytes as u64;
        if need > (self.bytes.len() - self.at) as u64 {
            return Err(MeshError::Truncated { what });
        }
        Ok(count as usize)
    }

    fn name(&mut self, what: &'static str, index: usize) -> Result<Option<String>, MeshError> {
        let len = self.u32(what)?;
        if len == NO_NAME {
            return Ok(None);
        }
        let padded = (len as usize).next_multiple_of(4);
        let bytes = self.take(padded, what)?;
        let name = std::str::from_utf8(&bytes[..len as usize])
            .map_err(|_| MeshError::BadName { what, index })?;
        Ok(Some(name.to_owned()))
    }
}

fn finite<const N: usize>(
    values: [f32; N],
    what: &'static str,
    index: usize,
) -> Result<[f32; N], MeshError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(values)
    } else {
        Err(MeshError::NonFinite { what, index })
    }
}

/// Decodes a scene mesh ([`encode_mesh`]'s format) into a scene: every count is checked against
/// the bytes present (and the input length against `limits.max_bytes`) before anything is
/// allocated; positions, normals and material and camera values must be finite, indices in
/// range, the three vertices of a triangle of one material. Degenerate triangles are dropped as
/// in [`Scene::from_triangles`]. Never panics.
pub fn decode_mesh(bytes: &[u8], limits: &Limits) -> Result<Scene, MeshError> {
    if bytes.len() as u64 > limits.max_bytes {
        return Err(MeshError::TooLarge {
            what: "file size",
            value: bytes.len() as u64,
            limit: limits.max_bytes,
        });
    }
    let mut r = Words { bytes, at: 0 };
    if r.take(8, "magic").ok() != Some(&MESH_MAGIC[..]) {
        return Err(MeshError::BadMagic);
    }
    let version = r.u32("header")?;
    if version != MESH_VERSION {
        return Err(MeshError::UnsupportedVersion(version));
    }
    let mut header = [0u32; 5];
    for word in &mut header {
        *word = r.u32("header")?;
    }
    let [vertices, triangles, materials, cameras, reserved] = header;
    if reserved != 0 {
        return Err(MeshError::Invalid {
            what: "header",
            index: 0,
            why: format!("reserved word is {reserved}, not 0"),
        });
    }
    // Positions, normals and a material index: 28 bytes per vertex.
    let vertex_count = r.fits(vertices, 28, "vertices")?;
    let mut positions = Vec::with_capacity(vertex_count);
    for i in 0..vertex_count {
        positions.push(Vec3::from_array(finite(
            r.f32s("positions")?,
            "position",
            i,
        )?));
    }
    for i in 0..vertex_count {
        finite(r.f32s::<3>("normals")?, "normal", i)?;
    }
    let material_count = materials as usize;
    let mut vertex_materials = Vec::with_capacity(vertex_count);
    for i in 0..vertex_count {
        let m = r.u32("vertex materials")?;
        if m >= materials {
            return Err(MeshError::OutOfRange {
                what: "vertex material of vertex",
                index: i,
                value: u64::from(m),
                len: material_count,
            });
        }
        vertex_materials.push(m);
    }
    let triangle_count = r.fits(triangles, 12, "indices")?;
    let mut corners = Vec::with_capacity(triangle_count);
    let mut material_ids = Vec::with_capacity(triangle_count);
    for t in 0..triangle_count {
        let mut tri = [Vec3::ZERO; 3];
        let mut material = None;
        for corner in &mut tri {
            let i = r.u32("indices")?;
            let (Some(&p), Some(&m)) =
                (positions.get(i as usize), vertex_materials.get(i as usize))
            else {
                return Err(MeshError::OutOfRange {
                    what: "index of triangle",
                    index: t,
                    value: u64::from(i),
                    len: vertex_count,
                });
            };
            if material.is_some_and(|first| first != m) {
                return Err(MeshError::MixedMaterials(t));
            }
            material = Some(m);
            *corner = p;
        }
        corners.push(tri);
        material_ids.push(material.unwrap_or(0));
    }
    // At least 32 bytes per material record and 80 per camera record.
    r.fits(materials, 32, "materials")?;
    let mut table = Vec::with_capacity(material_count);
    for i in 0..material_count {
        let albedo = finite(r.f32s::<3>("materials")?, "material", i)?;
        let emissive = finite(r.f32s::<3>("materials")?, "material", i)?;
        if albedo.iter().chain(&emissive).any(|&v| v < 0.0) {
            return Err(MeshError::Invalid {
                what: "material",
                index: i,
                why: "negative albedo or emission".into(),
            });
        }
        let flags = r.u32("materials")?;
        if flags & !DOUBLE_SIDED != 0 {
            return Err(MeshError::Invalid {
                what: "material",
                index: i,
                why: format!("unknown flags {flags:#x}"),
            });
        }
        let name = r.name("material", i)?.unwrap_or_default();
        table.push(Material {
            name,
            albedo: Vec3::from_array(albedo),
            emissive: Vec3::from_array(emissive),
            double_sided: flags & DOUBLE_SIDED != 0,
        });
    }
    let camera_count = r.fits(cameras, 80, "cameras")?;
    let mut views = Vec::with_capacity(camera_count);
    for i in 0..camera_count {
        let to_world = finite(r.f32s::<16>("cameras")?, "camera", i)?;
        let [yfov, aspect, znear] = finite(r.f32s::<3>("cameras")?, "camera", i)?;
        if !(yfov > 0.0 && yfov < std::f32::consts::PI) || aspect < 0.0 || znear < 0.0 {
            return Err(MeshError::Invalid {
                what: "camera",
                index: i,
                why: format!("yfov {yfov}, aspect ratio {aspect}, znear {znear}"),
            });
        }
        views.push(Camera {
            name: r.name("camera", i)?,
            to_world: Mat4::from_cols_array(&to_world),
            yfov,
            aspect_ratio: (aspect > 0.0).then_some(aspect),
            znear,
        });
    }
    if r.at != bytes.len() {
        return Err(MeshError::TrailingBytes(bytes.len() - r.at));
    }
    Ok(Scene::from_triangles(corners, material_ids, table)?.with_cameras(views))
}
