//! The bake: scene → transfer volume → MBD and baselines → scores → container.

use std::time::{Duration, Instant};

use prt_core::{Progress, resample_to_grid};
use prt_kernels::HatGrid;
use prt_mbd::{LocalBasis, MbdModel, PiecewisePcaModel, SolveReport};
use prt_texture::Limits;
use prt_texture::container::WriteReport;
use prt_trace::bricks::{BrickMap, BrickOptions, BrickStats};
use prt_trace::{BakeOptions, TransferBaker, TransferVolume};

use crate::container::{ContainerContents, read_container, write_container};
use crate::memory::MemoryEstimate;
use crate::methods::{basis_cells, fit_bpca, fit_cpca, fit_mbd};
use crate::scores::{Method, MethodScores, eval_options, score};
use crate::seams::{SeamView, seam_view, smooth};
use crate::{BakeConfig, BakeError, SceneInput};

/// A stage of the bake, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Tracing the transfer volume.
    Trace,
    /// Fitting MBD.
    Mbd,
    /// Scoring MBD.
    Evaluate,
    /// Fitting and scoring the baselines.
    Baselines,
    /// The seam view of every method.
    Seams,
    /// Writing the container and scoring the model read back.
    Write,
}

impl Stage {
    /// A short lower-case name ("trace", "mbd", ...).
    pub fn name(self) -> &'static str {
        match self {
            Stage::Trace => "trace",
            Stage::Mbd => "mbd",
            Stage::Evaluate => "evaluate",
            Stage::Baselines => "baselines",
            Stage::Seams => "seams",
            Stage::Write => "write",
        }
    }
}

/// How a bake reports its progress.
///
/// Every [`Progress`] is one: each stage's work reports through it, and a stage's start is
/// announced as its [`Progress::message`]. Implement this trait directly to give each stage
/// its own handle (a progress bar per stage) and to learn when a stage ends.
pub trait BakeProgress {
    /// Stage `stage` starts; its work reports through the returned handle until it is dropped.
    fn begin(&self, stage: Stage) -> Box<dyn Progress + '_>;

    /// Stage `stage` ended after `elapsed` (its handle is already dropped).
    fn end(&self, stage: Stage, elapsed: Duration) {
        let _ = (stage, elapsed);
    }
}

impl<P: Progress + ?Sized> BakeProgress for P {
    fn begin(&self, stage: Stage) -> Box<dyn Progress + '_> {
        self.message(stage.name());
        Box::new(Forward(self))
    }
}

/// A borrowed [`Progress`] as an owned handle.
struct Forward<'a, P: ?Sized>(&'a P);

impl<P: Progress + ?Sized> Progress for Forward<'_, P> {
    fn set_len(&self, len: u64) {
        self.0.set_len(len);
    }

    fn inc(&self, delta: u64) {
        self.0.inc(delta);
    }

    fn message(&self, msg: &str) {
        self.0.message(msg);
    }

    fn is_cancelled(&self) -> bool {
        self.0.is_cancelled()
    }
}

/// The fitted MBD model and what the report draws of it.
#[derive(Debug, Clone)]
pub struct BakedMbd {
    /// The model; its kernels are [`MbdModel::coefficient_kernels`] (one per voxel) and
    /// [`MbdModel::basis_kernels`] (the basis grid).
    pub model: MbdModel<HatGrid, HatGrid>,
    /// The solver's history.
    pub report: SolveReport,
    /// Basis-grid nodes per axis.
    pub basis_nodes: [usize; 3],
    /// The basis cell of every voxel.
    pub labels: Vec<u32>,
}

/// What a sparse-brick bake traced and stored ([`crate::Layout::Sparse`]).
#[derive(Debug, Clone)]
pub struct BrickSummary {
    /// The kept bricks and their indirection.
    pub map: BrickMap,
    /// Voxels probed, traced and stored, and the probe pass's time.
    pub stats: BrickStats,
}

/// A fitted baseline.
#[derive(Debug, Clone)]
pub struct Baseline {
    /// [`Method::Bpca`] or [`Method::Cpca`].
    pub method: Method,
    /// The model (labels, bases and coefficients on the grid).
    pub model: PiecewisePcaModel,
}

/// Everything a bake produced.
#[derive(Debug, Clone)]
pub struct Bake {
    /// The traced transfer volume (field, validity, tracer statistics); after a sparse bake,
    /// the kept bricks scattered into the grid (zero elsewhere).
    pub volume: TransferVolume,
    /// The bricks of a sparse bake (`None`: dense).
    pub bricks: Option<BrickSummary>,
    /// The MBD fit.
    pub mbd: BakedMbd,
    /// The baselines, BPCA then CPCA (empty when `config.baselines` is off).
    pub baselines: Vec<Baseline>,
    /// The comparison: MBD, MBD as written (when a container was written), then the baselines.
    pub comparison: Vec<MethodScores>,
    /// The seam view of MBD and then of each baseline, on the horizontal slice `seam_slice`.
    pub seam_views: Vec<(Method, SeamView)>,
    /// The voxel row `y` of the seam views' slice (the middle one).
    pub seam_slice: usize,
    /// What was written, when `config.container` is set.
    pub container: Option<WriteReport>,
    /// Wall time of every stage, in order.
    pub stage_times: Vec<(Stage, Duration)>,
}

/// Runs `f` as stage `stage`: a handle from `progress`, cancellation checked first, time recorded.
fn run_stage<T>(
    progress: &(impl BakeProgress + ?Sized),
    times: &mut Vec<(Stage, Duration)>,
    stage: Stage,
    f: impl FnOnce(&dyn Progress) -> Result<T, BakeError>,
) -> Result<T, BakeError> {
    let start = Instant::now();
    let handle = progress.begin(stage);
    handle.check().map_err(BakeError::Cancelled)?;
    let value = f(&*handle)?;
    drop(handle);
    let elapsed = start.elapsed();
    progress.end(stage, elapsed);
    times.push((stage, elapsed));
    Ok(value)
}

fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let start = Instant::now();
    let value = f();
    (value, start.elapsed())
}

/// Bakes `scene`: traces its transfer volume, fits MBD (and the baselines), scores every method,
/// computes the seam views and, when `config.container` is set, writes the container and scores
/// the model read back from it. Deterministic for `config.seed`.
pub fn bake(
    scene: &SceneInput,
    config: &BakeConfig,
    progress: &(impl BakeProgress + ?Sized),
) -> Result<Bake, BakeError> {
    config.validate()?;
    let bounds = scene.scene.bounds().ok_or_else(|| BakeError::EmptyScene {
        scene: scene.name.clone(),
    })?;
    if let Some(budget) = config.max_memory {
        let size = bounds.size().to_array();
        let triangles = scene.scene.triangles().len();
        MemoryEstimate::new(config, size, triangles).check(config, size, triangles, budget)?;
    }
    let mut times = Vec::new();
    let resolution = config.grid_resolution(bounds.size().to_array());
    let sparse = config.layout.is_sparse(resolution);
    let options = BakeOptions {
        resolution,
        margin: config.margin,
        rays_per_voxel: config.rays_per_voxel,
        cache_rays: config.cache_rays,
        seed: config.seed,
        adaptive: config.adaptive_sampling(),
        denoise: config.denoise_options(),
        ..BakeOptions::default()
    };
    let (volume, bricks) = run_stage(progress, &mut times, Stage::Trace, |p| {
        let baker = TransferBaker::new(&scene.scene, options).map_err(BakeError::TracerSetup)?;
        if !sparse {
            return Ok((baker.bake(p).map_err(BakeError::Trace)?, None));
        }
        let brick_options = BrickOptions {
            max_distance: config.brick_max_distance,
            ..BrickOptions::default()
        };
        let bricked = baker
            .bake_bricks(&brick_options, p)
            .map_err(BakeError::Trace)?;
        // The fits and scores below read a grid; the bricks are scattered into it once.
        let volume = bricked.to_dense().map_err(BakeError::Trace)?;
        let summary = BrickSummary {
            map: bricked.bricks,
            stats: bricked.brick_stats,
        };
        Ok((volume, Some(summary)))
    })?;
    let mut baked = bake_volume(&scene.name, volume, bricks, config, progress)?;
    times.append(&mut baked.stage_times);
    baked.stage_times = times;
    Ok(baked)
}

/// Every stage of [`bake`] after the trace, on a volume traced elsewhere (e.g. assembled from
/// tiles traced by separate workers): MBD, the baselines, the scores, the seam views and, when
/// `config.container` is set, the container. `scene_name` is recorded in the container;
/// `bricks` describes a sparse trace (`None` for a dense one). With a sparse layout
/// ([`crate::Layout::is_sparse`] for the volume's grid) the fits see the valid voxels only.
pub fn bake_volume(
    scene_name: &str,
    volume: TransferVolume,
    bricks: Option<BrickSummary>,
    config: &BakeConfig,
    progress: &(impl BakeProgress + ?Sized),
) -> Result<Bake, BakeError> {
    config.validate()?;
    let mut times = Vec::new();
    let field = &volume.field;
    let sparse = config.layout.is_sparse(field.dims());
    let mask = sparse.then_some(volume.valid.as_slice());

    // MBD, then the baselines at equal basis count (one rank-L basis per basis node).
    let basis_nodes = config.basis_grid(field.dims());
    let ((model, report), mbd_time) = run_stage(progress, &mut times, Stage::Mbd, |p| {
        let (fit, time) = timed(|| fit_mbd(field, mask, config, basis_nodes, p));
        Ok((fit.map_err(BakeError::Mbd)?, time))
    })?;

    let eval = eval_options(config.seed);
    let score_error = |method: Method| {
        move |source| BakeError::Score {
            method: method.name(),
            source,
        }
    };
    // Grid reconstructions are made for scoring and dropped: each is as large as the field.
    let (labels, mbd_scores) = run_stage(progress, &mut times, Stage::Evaluate, |_| {
        let labels = basis_cells(model.basis_kernels(), field).map_err(score_error(Method::Mbd))?;
        let reconstruction = resample_to_grid(&model, field.dims(), field.bounds())
            .map_err(|e| score_error(Method::Mbd)(e.into()))?;
        let scores = score(
            Method::Mbd,
            &model,
            field,
            &reconstruction,
            &labels,
            &eval,
            mbd_time,
        )
        .map_err(score_error(Method::Mbd))?;
        Ok((labels, scores))
    })?;
    let mut comparison = vec![mbd_scores];

    let mut baselines = Vec::new();
    if config.baselines {
        run_stage(progress, &mut times, Stage::Baselines, |p| {
            let clusters = basis_nodes.iter().product::<usize>();
            for method in [Method::Bpca, Method::Cpca] {
                let (fit, time) = timed(|| match method {
                    Method::Bpca => fit_bpca(field, config, basis_nodes, p),
                    _ => fit_cpca(field, mask, config, clusters, p),
                });
                let model = fit.map_err(|source| BakeError::Baseline {
                    method: if method == Method::Bpca {
                        "BPCA"
                    } else {
                        "CPCA"
                    },
                    source,
                })?;
                let reconstruction = model.reconstruct().map_err(score_error(method))?;
                comparison.push(
                    score(
                        method,
                        &model,
                        field,
                        &reconstruction,
                        model.labels(),
                        &eval,
                        time,
                    )
                    .map_err(score_error(method))?,
                );
                baselines.push(Baseline { method, model });
            }
            Ok(())
        })?;
    }

    // The seam view: each method's basis on the denoised reference.
    let seam_slice = field.dims()[1] / 2;
    let seam_views = run_stage(progress, &mut times, Stage::Seams, |_| {
        let smoothed = smooth(field, &volume.valid).map_err(score_error(Method::Mbd))?;
        let mbd_basis = LocalBasis::Moving {
            kernels: model.basis_kernels(),
            basis: model.basis(),
        };
        std::iter::once((Method::Mbd, labels.as_slice(), mbd_basis))
            .chain(baselines.iter().map(|b| {
                let basis = LocalBasis::Clustered {
                    labels: b.model.labels(),
                    bases: b.model.bases(),
                };
                (b.method, b.model.labels(), basis)
            }))
            .map(|(method, labels, basis)| {
                seam_view(&smoothed, &volume.valid, labels, &basis, seam_slice)
                    .map(|view| (method, view))
                    .map_err(score_error(method))
            })
            .collect::<Result<Vec<_>, _>>()
    })?;
    // The scores are MBD then the baselines, as the views.
    for (scores, (_, view)) in comparison.iter_mut().zip(&seam_views) {
        scores.denoised_seam_ratio = Some(view.seam_ratio);
    }

    let mut container = None;
    if let Some(folder) = &config.container {
        let (report, written_scores) = run_stage(progress, &mut times, Stage::Write, |_| {
            let contents = ContainerContents {
                model: &model,
                grid: field.dims(),
                valid: &volume.valid,
                scene: scene_name,
                lambda: config.lambda,
                encoding: config.encoding,
            };
            let report = write_container(folder, &contents).map_err(BakeError::Container)?;
            let bytes_per_voxel = report.bytes_per_voxel(field.num_voxels() as u64);
            // The error an engine will see: the model as read back from the files.
            let written = read_container(folder, &Limits::default())
                .map_err(BakeError::Container)?
                .model;
            let method = Method::MbdAsWritten(config.encoding);
            let reconstruction = resample_to_grid(&written, field.dims(), field.bounds())
                .map_err(|e| score_error(method)(e.into()))?;
            let mut scores = score(
                method,
                &written,
                field,
                &reconstruction,
                &labels,
                &eval,
                Duration::ZERO,
            )
            .map_err(score_error(method))?;
            scores.bytes_per_voxel = Some(bytes_per_voxel);
            Ok((report, scores))
        })?;
        comparison[0].bytes_per_voxel = written_scores.bytes_per_voxel;
        comparison.insert(1, written_scores);
        container = Some(report);
    }

    Ok(Bake {
        volume,
        bricks,
        mbd: BakedMbd {
            model,
            report,
            basis_nodes,
            labels,
        },
        baselines,
        comparison,
        seam_views,
        seam_slice,
        container,
        stage_times: times,
    })
}
