//! `prt export BAKE_DIR --target bevy|threejs|sh`: light a bake with a sky and write probe
//! volumes engines load unchanged (prt-export does the work; this module parses, draws progress
//! and reports what was written).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use prt_bake::BakeFolder;
use prt_bake::volumes::REFERENCE;
use prt_export::{
    AmbientCubeFit, BevyConfig, BevyFormat, DilateConfig, ShConfig, ThreejsConfig, WrittenFile,
    dilate, export_bevy, export_sh, export_threejs, remove_negative_light,
};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::LitVolume;

use crate::progress::StageBar;
use crate::sky::SkyArgs;

/// Which volume of a bake folder is lit (`prt export`, `prt render`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum VolumeArg {
    /// The traced transfer volume (from DIR/volumes/).
    Reference,
    /// The MBD container as written (DIR/mbd/), evaluated at the voxel centres.
    Mbd,
    /// Blockwise PCA's reconstruction (from DIR/volumes/).
    Bpca,
    /// Clustered PCA's reconstruction (from DIR/volumes/).
    Cpca,
}

impl VolumeArg {
    /// The volume's name in the bake folder.
    pub fn key(self) -> &'static str {
        match self {
            VolumeArg::Reference => REFERENCE,
            VolumeArg::Mbd => BakeFolder::CONTAINER,
            VolumeArg::Bpca => "bpca",
            VolumeArg::Cpca => "cpca",
        }
    }
}

/// The engine an export is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Target {
    /// Bevy's IrradianceVolume: ambient-cube KTX2 + irradiance_volume.json (Transform, intensity).
    Bevy,
    /// three.js LightProbeGrid: RGBA16F 3D atlas KTX2 + light_probe_grid.json (position, size).
    Threejs,
    /// L1 and L2 SH volumes (RGBA16F KTX2 3D textures and an EXR) + sh.json manifest.
    Sh,
}

/// Texel format of the Bevy texture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// E5B9G9R9_UFLOAT_PACK32 (4 bytes per texel).
    Rgb9e5,
    /// R16G16B16A16_SFLOAT (8 bytes per texel).
    Rgba16f,
}

/// How Bevy's ambient cubes are fitted to the SH irradiance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Fit {
    /// Each side is E(±axis)/π: exact on the six axes.
    Axes,
    /// Least squares of Bevy's blend over the sphere.
    LeastSquares,
}

/// Options of `prt export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// The folder `prt bake --out` wrote (its MBD container is BAKE_DIR/mbd/).
    pub bake_dir: PathBuf,
    /// The engine to export for.
    #[arg(long, value_enum)]
    pub target: Target,
    /// Which volume of the bake to light (`--from` is an older name for it).
    #[arg(long, value_enum, alias = "from", default_value_t = VolumeArg::Mbd)]
    pub method: VolumeArg,
    #[command(flatten)]
    pub sky: SkyArgs,
    /// Dilation of valid probes into invalid ones: `RADIUS[,PASSES]` (voxels; each pass fills
    /// every invalid voxel with valid or filled neighbours within RADIUS by their 1/d²-weighted
    /// mean; without PASSES, passes until every invalid voxel is filled), or `none`.
    #[arg(long, default_value = "1", value_name = "RADIUS[,PASSES]")]
    pub dilate: String,
    /// Texel format of the Bevy texture.
    #[arg(long, value_enum, default_value_t = Format::Rgb9e5)]
    pub format: Format,
    /// How the Bevy ambient cubes are fitted.
    #[arg(long, value_enum, default_value_t = Fit::Axes)]
    pub fit: Fit,
    /// The Bevy IrradianceVolume intensity written into irradiance_volume.json (converts the
    /// sky's units to cd/m²).
    #[arg(long, default_value_t = 1.0)]
    pub intensity: f32,
    /// Output folder [default: BAKE_DIR/TARGET].
    #[arg(long)]
    pub out: Option<PathBuf>,
}

fn parse_dilate(spec: &str) -> Result<DilateConfig> {
    if spec == "none" {
        return Ok(DilateConfig {
            radius: 0,
            passes: 0,
        });
    }
    let values = spec
        .split(',')
        .map(|v| v.trim().parse::<usize>())
        .collect::<Result<Vec<_>, _>>()
        .with_context(|| format!("--dilate {spec}: expected RADIUS[,PASSES] or none"))?;
    match values[..] {
        [radius] => Ok(DilateConfig {
            radius,
            passes: DilateConfig::UNTIL_FILLED,
        }),
        [radius, passes] => Ok(DilateConfig { radius, passes }),
        _ => bail!("--dilate {spec}: expected RADIUS[,PASSES] or none"),
    }
}

/// The volume `method` of the bake in `bake_dir` lit by `sky`: what `prt export` and `prt render`
/// light.
pub fn light_bake(bake_dir: &Path, method: VolumeArg, sky: &Sky) -> Result<LitVolume> {
    let stage = StageBar::start("light");
    let lit = BakeFolder::new(bake_dir)
        .lit_volume(method.key(), sky, &Limits::default(), &stage)
        .with_context(|| format!("--method {}", method.key()))?;
    stage.finish();
    Ok(lit)
}

/// What every engine export is made from: the lit bake with its invalid voxels filled by
/// `dilation` and its negative light removed (both counted on stderr).
pub fn prepare_for_engines(lit: &LitVolume, dilation: &DilateConfig) -> Result<LitVolume> {
    let dilated = dilate(lit, dilation)?;
    let clean = remove_negative_light(&dilated.volume)?;
    let [nx, ny, nz] = lit.dims;
    eprintln!(
        "{nx}x{ny}x{nz} voxels, {} valid; dilation filled {} invalid voxels, left {}; \
         negative irradiance removed from {} voxel channels (bands 1-2 scaled) and {} zeroed",
        lit.valid.iter().filter(|&&v| v).count(),
        dilated.filled,
        dilated.unfilled,
        clean.scaled,
        clean.zeroed
    );
    Ok(clean.volume)
}

pub fn run(args: &ExportArgs) -> Result<()> {
    let dilation = parse_dilate(&args.dilate)?;
    let sky = args.sky.sky()?;
    let start = Instant::now();
    let lit = light_bake(&args.bake_dir, args.method, &sky)?;
    let volume = prepare_for_engines(&lit, &dilation)?;
    let target = args
        .target
        .to_possible_value()
        .map(|v| v.get_name().to_string());
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| args.bake_dir.join(target.unwrap_or_default()));
    let files: Vec<WrittenFile> = match args.target {
        Target::Bevy => {
            let config = BevyConfig {
                format: match args.format {
                    Format::Rgb9e5 => BevyFormat::Rgb9e5,
                    Format::Rgba16f => BevyFormat::Rgba16f,
                },
                fit: match args.fit {
                    Fit::Axes => AmbientCubeFit::Axes,
                    Fit::LeastSquares => AmbientCubeFit::LeastSquares,
                },
                intensity: args.intensity,
            };
            let written = export_bevy(&volume, &config, &out)?;
            if written.clamped > 0 {
                eprintln!(
                    "{} ambient-cube values were negative (SH ringing) and stored as 0",
                    written.clamped
                );
            }
            written.files
        }
        Target::Threejs => export_threejs(&volume, &ThreejsConfig::default(), &out)?.files,
        Target::Sh => export_sh(&volume, &ShConfig::default(), &out)?.files,
    };
    for file in &files {
        println!("{:>10} bytes  {}", file.bytes, file.path.display());
    }
    eprintln!(
        "exported in {:.2} s to {}",
        start.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}
