//! What an engine's shader computes from an export: the probe lookup of Bevy and three.js on
//! the CPU, so that `prt render --lookup` shows what each engine will show.

use std::f32::consts::PI;

use glam::Vec3;
use prt_trace::LitVolume;
use prt_trace::lit::irradiance;

use crate::ambient::ambient_cube;
use crate::threejs::ENGINE_PADDING;
use crate::{AmbientCubeFit, ExportError};

/// An engine whose probe lookup [`EngineLookup`] reproduces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Engine {
    /// Bevy 0.19's `IrradianceVolume` (bevy_pbr's irradiance_volume.wgsl and light_probe.wgsl):
    /// the ambient cube interpolated at the surface point itself, with no normal offset, the
    /// light-probe weight of the box's faces, sides blended by Valve's `n²` rule.
    Bevy,
    /// three.js 0.187's `LightProbeGrid` (lightprobes_pars_fragment): the radiance SH
    /// interpolated half a probe spacing off the surface along its normal, clamped to the
    /// outermost probe centres, convolved to irradiance and clamped at 0.
    Threejs,
}

/// An export as an engine samples it: the padded grid the exporter writes and the engine's
/// lookup rule, evaluated in f32 without the texture format's rounding.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineLookup {
    engine: Engine,
    grid: LitVolume,
    /// Bevy: per voxel, the six sides (+x −x +y −y +z −z) of `E/π`, negatives stored as 0.
    cubes: Vec<[Vec3; 6]>,
}

impl EngineLookup {
    /// The lookup of `engine` over the export of `volume` (the lit volume as given to
    /// [`export_bevy`](crate::export_bevy) or [`export_threejs`](crate::export_threejs), i.e.
    /// after dilation), with Bevy's sides fitted by `fit`.
    pub fn new(
        volume: &LitVolume,
        engine: Engine,
        fit: AmbientCubeFit,
    ) -> Result<Self, ExportError> {
        volume.check()?;
        let grid = volume.padded(ENGINE_PADDING);
        let cubes = match engine {
            Engine::Bevy => grid
                .radiance
                .iter()
                .map(|l| ambient_cube(l, fit).map(|side| Vec3::from_array(side).max(Vec3::ZERO)))
                .collect(),
            Engine::Threejs => Vec::new(),
        };
        Ok(Self {
            engine,
            grid,
            cubes,
        })
    }

    /// Diffuse irradiance (RGB) the engine computes for a surface point `position` with unit
    /// normal `normal`; `None` where the engine's probe box does not light it.
    pub fn irradiance(&self, position: Vec3, normal: Vec3) -> Option<Vec3> {
        let grid = &self.grid;
        let size = grid.bounds.size();
        match self.engine {
            Engine::Bevy => {
                let unit = (position - grid.bounds.centre()) / size;
                // light_probe.wgsl: saturate((1 − 2|p|) / (2 · max(falloff, 1e-4))), falloff 0.
                let weight = ((Vec3::ONE - 2.0 * unit.abs()) / 2e-4)
                    .clamp(Vec3::ZERO, Vec3::ONE)
                    .min_element();
                if weight <= 0.0 {
                    return None;
                }
                let corners = grid.trilinear(position);
                let side = |s: usize| -> Vec3 {
                    corners
                        .iter()
                        .map(|&(v, w)| w * self.cubes[v][s])
                        .fold(Vec3::ZERO, |a, b| a + b)
                };
                let pick = |axis: usize, c: f32| side(2 * axis + usize::from(c < 0.0));
                let nn = normal * normal;
                let blend =
                    pick(0, normal.x) * nn.x + pick(1, normal.y) * nn.y + pick(2, normal.z) * nn.z;
                Some(weight * PI * blend)
            }
            Engine::Threejs => {
                let spacing = size / Vec3::from_array(grid.dims.map(|d| d as f32));
                let sample = position + normal * spacing * 0.5;
                let margin = spacing * 0.01;
                if sample.cmplt(grid.bounds.min - margin).any()
                    || sample.cmpgt(grid.bounds.max + margin).any()
                {
                    return None;
                }
                let mut l = [[0.0f32; 9]; 3];
                for (v, w) in grid.trilinear(sample) {
                    for c in 0..3 {
                        for j in 0..9 {
                            l[c][j] += w * grid.radiance[v][c][j];
                        }
                    }
                }
                Some(Vec3::from_array(l.map(|l| irradiance(&l, normal))).max(Vec3::ZERO))
            }
        }
    }
}
