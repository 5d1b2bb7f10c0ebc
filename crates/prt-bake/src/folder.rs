//! The bake folder: what `prt bake --out DIR` (and `prt merge`) writes and what `prt render`,
//! `prt export` and `prt view` read, named in one place.

use std::path::{Path, PathBuf};

use prt_core::{GridField, Progress};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::{LitVolume, TraceError};
use thiserror::Error;

use prt_texture::Encoding;
use prt_texture::container::WriteReport;

use crate::Bake;
use crate::container::{ContainerError, MbdContainer, read_container};
use crate::volumes::{KeptVolumes, kept_volume_bytes, read_volumes, write_volumes};

/// A bake folder's layout. Only the paths: nothing is read until asked, so a folder being
/// written can be named too.
///
/// | path | what | written by |
/// |---|---|---|
/// | [`CONTAINER`](Self::CONTAINER)`/` | the MBD container (KTX2 volumes + manifest) | `prt bake`, `prt merge` |
/// | [`VOLUMES`](Self::VOLUMES)`/` | the kept volumes: the traced reference and the baselines | `--keep-volumes` |
/// | [`SCENE_MESH`](Self::SCENE_MESH) | the scene's triangles, materials and cameras | `prt bake`, `prt merge` |
/// | [`REPORT_MD`](Self::REPORT_MD), [`REPORT_JSON`](Self::REPORT_JSON) | the comparison and the image metrics | `prt bake`, `prt merge` |
/// | [`TILES_REPORT`](Self::TILES_REPORT) | the tiles a merge assembled, with seam measures | `prt merge` |
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BakeFolder {
    root: PathBuf,
}

/// Whether a bake keeps its traced volume and the baselines' reconstructions (`volumes/`),
/// which exports, renders and the viewer compare against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KeepVolumes {
    /// Keep them when they take at most [`KeepVolumes::AUTO_BYTES`] (f16).
    #[default]
    Auto,
    /// Always keep them.
    Always,
    /// Never keep them.
    Never,
}

impl KeepVolumes {
    /// The most bytes [`KeepVolumes::Auto`] keeps.
    pub const AUTO_BYTES: u64 = 512 << 20;
}

/// What [`BakeFolder::keep_volumes`] did.
#[derive(Debug)]
pub enum KeptOutcome {
    /// Written (f16).
    Written(WriteReport),
    /// Not written: [`KeepVolumes::Auto`] and over [`KeepVolumes::AUTO_BYTES`].
    OverAutoLimit {
        /// Bytes they would have taken.
        bytes: u64,
    },
    /// Not written: [`KeepVolumes::Never`].
    NotAsked,
}

/// One of a bake folder's transfer volumes, read back for lighting.
#[derive(Debug)]
pub enum FolderVolume {
    /// The MBD container: a model evaluated anywhere in the baked box.
    Mbd(Box<MbdContainer>),
    /// A kept volume, voxel by voxel.
    Kept {
        /// Its name among the kept volumes (`reference`, `bpca`, `cpca`).
        name: String,
        /// The 324-D transfer per voxel.
        field: GridField,
        /// Per voxel: whether the transfer is meaningful.
        valid: Vec<bool>,
    },
}

/// What can go wrong reading a bake folder.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum FolderError {
    /// The folder has no MBD container.
    #[error("{} holds no MBD container (expected {}, written by `prt bake --out`)", .root.display(), .manifest.display())]
    NoContainer {
        /// The bake folder.
        root: PathBuf,
        /// The manifest that is missing.
        manifest: PathBuf,
    },
    /// The folder has no kept volumes.
    #[error("{} holds no kept volumes (`prt bake --keep-volumes always` writes them)", .dir.display())]
    NoVolumes {
        /// The kept volumes' folder that is missing.
        dir: PathBuf,
    },
    /// The folder has no scene mesh.
    #[error("{} has no {}: is it a folder written by `prt bake --out`?", .root.display(), BakeFolder::SCENE_MESH)]
    NoSceneMesh {
        /// The bake folder.
        root: PathBuf,
    },
    /// The asked volume is neither `mbd` nor among the kept ones.
    #[error("`{name}` is not among the kept volumes ({}) nor `{}`", .kept.join(", "), BakeFolder::CONTAINER)]
    UnknownVolume {
        /// The name asked for.
        name: String,
        /// The names kept.
        kept: Vec<String>,
    },
    /// A container in the folder cannot be written.
    #[error("cannot write {}", .path.display())]
    Write {
        /// The container's folder.
        path: PathBuf,
        /// Why.
        #[source]
        source: ContainerError,
    },
    /// A container in the folder cannot be read.
    #[error("cannot read {}", .path.display())]
    Read {
        /// The container's folder.
        path: PathBuf,
        /// Why.
        #[source]
        source: ContainerError,
    },
    /// A volume read back cannot be lit (not a transfer volume, inconsistent, cancelled).
    #[error("cannot light the `{name}` volume")]
    Light {
        /// The volume's name (`mbd`, `reference`, ...).
        name: String,
        /// Why.
        #[source]
        source: TraceError,
    },
}

impl BakeFolder {
    /// The MBD container's folder, and the name that picks it among the folder's volumes.
    pub const CONTAINER: &'static str = "mbd";
    /// The kept volumes' folder.
    pub const VOLUMES: &'static str = "volumes";
    /// The scene mesh file (prt-render's format).
    pub const SCENE_MESH: &'static str = "scene.mesh";
    /// The report a person reads.
    pub const REPORT_MD: &'static str = "report.md";
    /// The report's figures for programs.
    pub const REPORT_JSON: &'static str = "report.json";
    /// The record of a merge's tiles.
    pub const TILES_REPORT: &'static str = "tiles.json";

    /// The bake folder at `root`.
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// The folder itself.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The MBD container's folder.
    pub fn container_dir(&self) -> PathBuf {
        self.root.join(Self::CONTAINER)
    }

    /// The kept volumes' folder.
    pub fn volumes_dir(&self) -> PathBuf {
        self.root.join(Self::VOLUMES)
    }

    /// The scene mesh file.
    pub fn scene_mesh(&self) -> PathBuf {
        self.root.join(Self::SCENE_MESH)
    }

    /// `report.md`.
    pub fn report_md(&self) -> PathBuf {
        self.root.join(Self::REPORT_MD)
    }

    /// `report.json`.
    pub fn report_json(&self) -> PathBuf {
        self.root.join(Self::REPORT_JSON)
    }

    /// `tiles.json`.
    pub fn tiles_report(&self) -> PathBuf {
        self.root.join(Self::TILES_REPORT)
    }

    /// Whether the folder holds an MBD container (its manifest exists).
    pub fn has_container(&self) -> bool {
        self.container_dir().join("manifest.json").is_file()
    }

    /// Whether the folder holds kept volumes (their manifest exists).
    pub fn has_volumes(&self) -> bool {
        self.volumes_dir().join("manifest.json").is_file()
    }

    /// The scene mesh's path, or why there is none.
    pub fn existing_scene_mesh(&self) -> Result<PathBuf, FolderError> {
        let path = self.scene_mesh();
        if path.is_file() {
            Ok(path)
        } else {
            Err(FolderError::NoSceneMesh {
                root: self.root.clone(),
            })
        }
    }

    /// Reads the MBD container.
    pub fn read_container(&self, limits: &Limits) -> Result<MbdContainer, FolderError> {
        let dir = self.container_dir();
        if !self.has_container() {
            return Err(FolderError::NoContainer {
                root: self.root.clone(),
                manifest: dir.join("manifest.json"),
            });
        }
        read_container(&dir, limits).map_err(|source| FolderError::Read { path: dir, source })
    }

    /// Reads every kept volume.
    pub fn read_volumes(&self, limits: &Limits) -> Result<KeptVolumes, FolderError> {
        let dir = self.volumes_dir();
        if !self.has_volumes() {
            return Err(FolderError::NoVolumes { dir });
        }
        read_volumes(&dir, limits).map_err(|source| FolderError::Read { path: dir, source })
    }

    /// Writes the kept volumes of `bake` (f16) into [`volumes_dir`](Self::volumes_dir) as
    /// `policy` says.
    pub fn keep_volumes(
        &self,
        bake: &Bake,
        policy: KeepVolumes,
    ) -> Result<KeptOutcome, FolderError> {
        let bytes = kept_volume_bytes(bake, Encoding::F16);
        match policy {
            KeepVolumes::Never => return Ok(KeptOutcome::NotAsked),
            KeepVolumes::Auto if bytes > KeepVolumes::AUTO_BYTES => {
                return Ok(KeptOutcome::OverAutoLimit { bytes });
            }
            KeepVolumes::Auto | KeepVolumes::Always => {}
        }
        let dir = self.volumes_dir();
        write_volumes(&dir, bake, Encoding::F16)
            .map(KeptOutcome::Written)
            .map_err(|source| FolderError::Write { path: dir, source })
    }

    /// Reads the volume named `name`: [`CONTAINER`](Self::CONTAINER) (`mbd`) for the MBD
    /// container, otherwise a kept volume (`reference`, `bpca`, `cpca`).
    pub fn read_volume(&self, name: &str, limits: &Limits) -> Result<FolderVolume, FolderError> {
        if name == Self::CONTAINER {
            return Ok(FolderVolume::Mbd(Box::new(self.read_container(limits)?)));
        }
        let kept = self.read_volumes(limits)?;
        let KeptVolumes { valid, volumes, .. } = kept;
        let names: Vec<String> = volumes.iter().map(|(n, _)| n.clone()).collect();
        let Some((name, field)) = volumes.into_iter().find(|(n, _)| n == name) else {
            return Err(FolderError::UnknownVolume {
                name: name.to_string(),
                kept: names,
            });
        };
        Ok(FolderVolume::Kept { name, field, valid })
    }

    /// The volume named `name` (as [`read_volume`](Self::read_volume) takes it) lit by `sky`:
    /// what `prt render`, `prt export` and the bake's report light, read the one way.
    pub fn lit_volume(
        &self,
        name: &str,
        sky: &Sky,
        limits: &Limits,
        progress: &dyn Progress,
    ) -> Result<LitVolume, FolderError> {
        self.read_volume(name, limits)?
            .light(sky, progress)
            .map_err(|source| FolderError::Light {
                name: name.to_string(),
                source,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_folder_names_what_is_missing() {
        let dir = std::env::temp_dir().join(format!("prt-folder-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let folder = BakeFolder::new(&dir);
        let limits = Limits::default();
        let missing = folder.read_container(&limits).unwrap_err().to_string();
        assert!(missing.contains("mbd/manifest.json"), "{missing}");
        assert!(matches!(
            folder.read_volume("reference", &limits),
            Err(FolderError::NoVolumes { .. })
        ));
        assert!(matches!(
            folder.existing_scene_mesh(),
            Err(FolderError::NoSceneMesh { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
