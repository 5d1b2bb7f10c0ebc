//! The streamed merge (`merge_streamed`): the same model on any number of threads, sweeps that
//! never raise its (loss-weighted) error, an error close to the in-memory merge's, a container
//! that reads back, the in-memory fit's loss weighting, and the distributed merge's bytes.

use std::path::PathBuf;

use prt_bake::container::read_container;
use prt_bake::tiles::{
    MapOutcome, MergeStage, PartialError, TileError, TilePlan, assemble, bake_tile, map_tile,
    merge_from_partials, merge_streamed, partial_path, plan_tiles, reduce_stage,
};
use prt_bake::{BakeConfig, SceneInput, bake_volume};
use prt_core::{FieldModel, GridField, NoProgress};
use prt_mbd::LossWeighting;
use prt_texture::Limits;

mod common;
use common::scratch;

fn on_threads<T: Send>(threads: usize, run: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
        .install(run)
}

/// `Σ‖f − f̂‖² / Σ‖f‖²` over the valid voxel centres.
fn centre_error(model: &dyn FieldModel, field: &GridField, valid: &[bool]) -> f64 {
    let mut out = vec![0.0f32; field.dim()];
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for v in (0..field.num_voxels()).filter(|&v| valid[v]) {
        model.eval(field.centre_of(v), &mut out).expect("eval");
        for (&a, &b) in field.voxel(v).iter().zip(&out) {
            num += f64::from(a - b).powi(2);
            den += f64::from(a).powi(2);
        }
    }
    num / den
}

/// A small Cornell bake planned as 2 × 2 × 1 tiles in the scratch folder `name`, every tile
/// traced: the bake's knobs, the plan and its folder.
fn traced_tiles(
    resolution: usize,
    basis_nodes: usize,
    max_iterations: usize,
    name: &str,
) -> (BakeConfig, TilePlan, PathBuf) {
    let scene = SceneInput::cornell_box();
    let config = BakeConfig {
        resolution,
        rays_per_voxel: 24,
        cache_rays: 8,
        rank: 4,
        basis_nodes,
        max_iterations,
        baselines: false,
        ..BakeConfig::default()
    };
    let plan = plan_tiles(&scene, None, &config, [2, 2, 1], 1).expect("plan");
    let dir = scratch(name);
    plan.write(&dir).expect("plan written");
    for index in 0..plan.tiles.len() {
        bake_tile(&plan, &dir, &scene, index, false, &NoProgress).expect("tile");
    }
    (config, plan, dir)
}

#[test]
fn the_streamed_merge_is_deterministic_descends_and_comes_close_to_the_in_memory_merge() {
    let (config, plan, dir) = traced_tiles(16, 4, 24, "stream");
    let out = scratch("stream-out");
    let streamed_config = BakeConfig {
        container: Some(out.join("mbd")),
        ..config.clone()
    };
    let merge = |threads| {
        on_threads(threads, || {
            merge_streamed(
                &plan,
                &dir,
                "cornell",
                &streamed_config,
                3,
                &Limits::default(),
                &NoProgress,
            )
            .expect("streamed merge")
        })
    };
    let (one, three) = (merge(1), merge(3));
    let (one_model, three_model) = (one.model.as_ref().unwrap(), three.model.as_ref().unwrap());
    assert_eq!(one_model.coefficients(), three_model.coefficients());
    assert_eq!(one_model.basis(), three_model.basis());
    assert_eq!(one.relative_errors, three.relative_errors);
    assert_eq!(one.weighted_errors, three.weighted_errors);

    // Each sweep lowers the loss, weighted per voxel by default (its residual term may rise by
    // the ridge's order only).
    assert!(config.loss_weighting.is_some());
    let errors = &one.relative_errors;
    assert_eq!((errors.len(), one.weighted_errors.len()), (4, 4));
    for pair in one.weighted_errors.windows(2) {
        assert!(
            pair[1] <= pair[0] * (1.0 + 1e-3),
            "{:?}",
            one.weighted_errors
        );
    }

    // Against the in-memory merge of the same tiles, on the same voxels.
    let assembled = assemble(&plan, &dir, &Limits::default()).expect("assembled");
    let field = assembled.volume.field.clone();
    let valid = assembled.volume.valid.clone();
    assert_eq!(Some(&valid), one.valid.as_ref());
    assert_eq!(
        one.valid_voxels,
        valid.iter().filter(|&&v| v).count() as u64
    );
    let in_memory = bake_volume("cornell", assembled.volume, None, &config, &NoProgress)
        .expect("in-memory merge");
    let streamed_error = centre_error(one_model, &field, &valid);
    let in_memory_error = centre_error(&in_memory.mbd.model, &field, &valid);
    println!(
        "voxel-centre relative error: streamed {errors:?} (checked {streamed_error:.4e}), \
         in memory {in_memory_error:.4e}"
    );
    assert!((streamed_error - errors[3]).abs() <= 1e-3 * errors[3]);
    assert!(
        streamed_error <= 1.25 * in_memory_error,
        "streamed {streamed_error:.4e} against in memory {in_memory_error:.4e}"
    );

    // The container reads back as the model, up to its f16 storage.
    let back = read_container(&out.join("mbd"), &Limits::default()).expect("container");
    assert_eq!(back.valid, valid);
    let back_error = centre_error(&back.model, &field, &valid);
    assert!(
        back_error <= streamed_error * 1.01 + 1e-6,
        "{back_error} vs {streamed_error}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&out);
}

/// Every file under `dir`, relative, with its bytes.
fn tree(dir: &std::path::Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).expect("folder").flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let bytes = std::fs::read(&path).expect("file");
                out.push((path.strip_prefix(dir).unwrap().to_path_buf(), bytes));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn the_distributed_merge_writes_the_streamed_merges_bytes_and_refuses_stale_partials() {
    let (config, plan, dir) = traced_tiles(12, 3, 16, "distributed");
    let limits = Limits::default();
    let sweeps = 2;
    let with_container = |name: &str| BakeConfig {
        container: Some(scratch(name).join("mbd")),
        ..config.clone()
    };
    let local = with_container("distributed-local");
    let streamed = merge_streamed(&plan, &dir, "cornell", &local, sweeps, &limits, &NoProgress)
        .expect("streamed merge");

    // Each stage as separate maps and a reduce through the plan folder's files.
    let distributed = with_container("distributed-files");
    for stage in MergeStage::all(sweeps) {
        for tile in 0..plan.tiles.len() {
            let outcome = map_tile(&plan, &dir, &config, sweeps, stage, tile, &limits).unwrap();
            assert!(matches!(outcome, MapOutcome::Written { .. }), "{outcome:?}");
        }
        if stage != MergeStage::Coefficients {
            reduce_stage(&plan, &dir, &config, sweeps, stage, &limits, &NoProgress).unwrap();
        }
    }
    let merged = merge_from_partials(
        &plan,
        &dir,
        "cornell",
        &distributed,
        sweeps,
        &limits,
        &NoProgress,
    )
    .expect("reduce of the coefficients");
    assert_eq!(merged.relative_errors, streamed.relative_errors);
    assert_eq!(merged.weighted_errors, streamed.weighted_errors);
    assert_eq!(merged.valid_voxels, streamed.valid_voxels);
    assert_eq!(merged.mean_magnitude, streamed.mean_magnitude);
    assert_eq!(merged.basis_solves, streamed.basis_solves);
    let (a, b) = (
        tree(local.container.as_ref().unwrap()),
        tree(distributed.container.as_ref().unwrap()),
    );
    assert!(a.len() >= 2 && a == b, "the containers differ");
    // A requeued map finds its partial current.
    let again = map_tile(
        &plan,
        &dir,
        &config,
        sweeps,
        MergeStage::Sweep(1),
        2,
        &limits,
    )
    .unwrap();
    assert!(matches!(again, MapOutcome::AlreadyDone { .. }), "{again:?}");

    // A partial of another stage in a sweep's place: stale, naming the file.
    let part = |stage, tile| partial_path(&dir, stage, tile);
    std::fs::copy(part(MergeStage::Sweep(2), 0), part(MergeStage::Sweep(1), 0)).unwrap();
    let error = reduce_stage(
        &plan,
        &dir,
        &config,
        sweeps,
        MergeStage::Sweep(1),
        &limits,
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(&error, TileError::Partial(PartialError::Stale { path, .. }) if path.ends_with("sweep-1/tile-0.part")),
        "{error}"
    );
    // A flipped payload byte: the checksum refuses it.
    let coarse = part(MergeStage::Coarse, 1);
    let mut bytes = std::fs::read(&coarse).unwrap();
    *bytes.last_mut().unwrap() ^= 1;
    std::fs::write(&coarse, &bytes).unwrap();
    let error = reduce_stage(
        &plan,
        &dir,
        &config,
        sweeps,
        MergeStage::Coarse,
        &limits,
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(&error, TileError::Partial(PartialError::Malformed { why, .. }) if why.contains("checksum")),
        "{error}"
    );
    // The coefficients mapped on another basis (one sweep): not current, mapped again; then
    // stale for the merge of two sweeps.
    let remapped = map_tile(
        &plan,
        &dir,
        &config,
        1,
        MergeStage::Coefficients,
        0,
        &limits,
    )
    .unwrap();
    assert!(
        matches!(remapped, MapOutcome::Written { .. }),
        "{remapped:?}"
    );
    let error = merge_from_partials(
        &plan,
        &dir,
        "cornell",
        &distributed,
        sweeps,
        &limits,
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(&error, TileError::Partial(PartialError::Stale { .. })),
        "{error}"
    );
    // A missing partial is named with the command that makes it.
    std::fs::remove_file(part(MergeStage::Coefficients, 3)).unwrap();
    std::fs::remove_file(part(MergeStage::Coefficients, 0)).unwrap();
    let error = merge_from_partials(
        &plan,
        &dir,
        "cornell",
        &distributed,
        sweeps,
        &limits,
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        error
            .to_string()
            .contains("--map --stage coefficients --tile 0"),
        "{error}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    for config in [local, distributed] {
        let _ = std::fs::remove_dir_all(config.container.unwrap().parent().unwrap());
    }
}

#[test]
fn the_streamed_merge_weights_as_the_in_memory_fit_and_exponent_zero_is_the_papers_loss() {
    let (config, plan, dir) = traced_tiles(12, 3, 16, "weighting");
    let merge = |loss_weighting, name: &str| {
        let config = BakeConfig {
            loss_weighting,
            container: Some(scratch(name).join("mbd")),
            ..config.clone()
        };
        let merged = merge_streamed(
            &plan,
            &dir,
            "cornell",
            &config,
            1,
            &Limits::default(),
            &NoProgress,
        )
        .expect("streamed merge");
        let folder = config.container.unwrap();
        let files = tree(&folder);
        let _ = std::fs::remove_dir_all(folder.parent().unwrap());
        (merged, files)
    };
    // The weights' normalisation is the in-memory fit's: the valid voxels' mean magnitude.
    let weighted = merge(Some(LossWeighting::default()), "weighting-relative");
    let volume = assemble(&plan, &dir, &Limits::default())
        .expect("assembled")
        .volume;
    let magnitudes: Vec<f64> = (0..volume.field.num_voxels())
        .filter(|&v| volume.valid[v])
        .map(|v| LossWeighting::magnitude(volume.field.voxel(v)))
        .collect();
    let mean = magnitudes.iter().sum::<f64>() / magnitudes.len() as f64;
    assert!(
        (weighted.0.mean_magnitude - mean).abs() <= 1e-12 * mean,
        "{} vs {mean}",
        weighted.0.mean_magnitude
    );
    // Exponent 0 weighs every voxel 1: the bytes of the paper's loss.
    let paper = merge(None, "weighting-none");
    let zero = merge(
        Some(LossWeighting {
            exponent: 0.0,
            ..LossWeighting::default()
        }),
        "weighting-zero",
    );
    assert!(
        paper.1.len() >= 2 && paper.1 == zero.1,
        "exponent 0 is not the paper's loss"
    );
    assert_eq!(paper.0.relative_errors, paper.0.weighted_errors);
    assert_eq!(paper.0.relative_errors, zero.0.relative_errors);
    // The weighting changes the fit.
    assert!(weighted.1 != paper.1);
    let _ = std::fs::remove_dir_all(&dir);
}
