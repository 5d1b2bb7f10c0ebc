//! The relighting engine against the dense product, the transport's truncation and
//! quantisation bounds, and its errors.

use ndarray::Array2;
use prt_core::{AtomicProgress, CoreError, DenseOracle, MatrixOracle, NoProgress};
use prt_wavelet::{Approximator, BandStrategy, Policy, Relighter, SparseTransport, WaveletError};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn sparse_matrix(rows: usize, cols: usize, density: f64, rng: &mut Pcg64) -> Array2<f32> {
    Array2::from_shape_fn((rows, cols), |_| {
        if rng.random_bool(density) {
            rng.random_range(-1.0f32..1.0) * 10f32.powi(rng.random_range(-3..3))
        } else {
            0.0
        }
    })
}

#[test]
fn truncation_keeps_the_largest_per_row_and_quantisation_is_bounded() {
    let mut rng = Pcg64::seed_from_u64(7);
    let dense = sparse_matrix(40, 64, 0.4, &mut rng);
    let oracle = DenseOracle::new(dense.clone(), 1).unwrap();
    let keep = 6;
    let t = SparseTransport::from_oracle(&oracle, keep, &NoProgress).unwrap();
    let deq = t.to_dense();
    let mut scale = vec![0.0f32; 64];
    for r in 0..40 {
        let row: Vec<f32> = dense.row(r).to_vec();
        let mut mags: Vec<f32> = row.iter().map(|v| v.abs()).filter(|v| *v > 0.0).collect();
        mags.sort_by(|a, b| b.total_cmp(a));
        let threshold = mags.get(keep - 1).copied().unwrap_or(0.0);
        let kept = (0..64)
            .filter(|&j| deq[r * 64 + j] != 0.0 || (row[j] != 0.0 && row[j].abs() >= threshold))
            .count();
        assert_eq!(kept, mags.len().min(keep), "row {r}");
        for j in 0..64 {
            if row[j].abs() >= threshold && row[j] != 0.0 {
                scale[j] = scale[j].max(row[j].abs());
            }
        }
    }
    for r in 0..40 {
        for j in 0..64 {
            let (d, o) = (deq[r * 64 + j], dense[[r, j]]);
            if d != 0.0 {
                assert!(
                    (d - o).abs() <= scale[j] / 32767.0 * 0.5 + 1e-12,
                    "({r},{j}): {d} vs {o}"
                );
            }
        }
    }
    assert!(t.nnz() <= 40 * keep);
    let norms = t.column_l1_norms();
    for j in 0..64 {
        let s: f32 = (0..40).map(|r| deq[r * 64 + j].abs()).sum();
        assert!((norms[j] - s).abs() <= 1e-4 * (1.0 + s));
    }
}

#[test]
fn engine_matches_the_dense_product_for_every_policy() {
    for channels in [1, 2, 3, 5] {
        dense_check(channels);
    }
}

fn dense_check(channels: usize) {
    let mut rng = Pcg64::seed_from_u64(11);
    let (rows, cols) = (50, 48);
    let oracle = DenseOracle::new(sparse_matrix(rows, cols, 0.3, &mut rng), 1).unwrap();
    // Tiles of 8 pixels (the last one partial) so that the tiled apply is what is checked.
    let t = SparseTransport::from_oracle(&oracle, 10, &NoProgress)
        .unwrap()
        .with_tile_rows(8);
    assert_eq!((t.tile_rows(), t.tiles()), (8, 7));
    let deq = t.to_dense();
    let bands: Vec<u8> = (0..cols).map(|j| (j % 4) as u8).collect();
    for policy in [
        Policy::NonIncremental,
        Policy::Incremental,
        Policy::PerBand(BandStrategy::L1Test),
        Policy::PerBand(BandStrategy::Exhaustive),
        Policy::PerBand(BandStrategy::Dealer),
    ] {
        let mut a =
            Approximator::new(bands.clone(), t.column_l1_norms(), channels, 7, policy).unwrap();
        let mut engine = Relighter::new(t.clone(), channels, 4).unwrap();
        let mut lighting: Vec<f32> = (0..cols * channels)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect();
        for frame in 0..25 {
            // A drifting lighting with occasional jumps, then static.
            if frame < 18 {
                for v in &mut lighting {
                    *v += rng.random_range(-0.2f32..0.2)
                        + if frame % 7 == 6 {
                            rng.random_range(-2.0f32..2.0)
                        } else {
                            0.0
                        };
                }
            }
            let update = a.step(&lighting).unwrap().clone();
            engine.apply(&update).unwrap();
            let approx = a.approximation();
            for c in 0..channels {
                for r in 0..rows {
                    let exact: f64 = (0..cols)
                        .map(|j| deq[r * cols + j] as f64 * approx[c * cols + j] as f64)
                        .sum();
                    let scale: f64 = (0..cols)
                        .map(|j| (deq[r * cols + j] as f64 * approx[c * cols + j] as f64).abs())
                        .sum();
                    let got = engine.image()[r * channels + c] as f64;
                    assert!(
                        (got - exact).abs() <= 1e-4 * (1.0 + scale),
                        "{policy:?} frame {frame}: {got} vs {exact}"
                    );
                }
            }
        }
    }
}

#[test]
fn tiling_never_changes_the_image() {
    // Per pixel, terms are accumulated in the same (band) order whatever the tiling, so every
    // tile size gives bit-identical images.
    let mut rng = Pcg64::seed_from_u64(3);
    let (rows, cols) = (37, 40);
    let oracle = DenseOracle::new(sparse_matrix(rows, cols, 0.4, &mut rng), 1).unwrap();
    let t = SparseTransport::from_oracle(&oracle, 12, &NoProgress).unwrap();
    assert_eq!(t.tiles(), 1, "37 pixels fit in one default tile");
    let bands: Vec<u8> = (0..cols).map(|j| (j % 3) as u8).collect();
    for channels in [1, 3, 5] {
        for policy in [
            Policy::NonIncremental,
            Policy::PerBand(BandStrategy::Exhaustive),
        ] {
            let mut engines: Vec<Relighter> = [rows, 1, 5, 16, 1000]
                .iter()
                .map(|&n| Relighter::new(t.clone().with_tile_rows(n), channels, 3).unwrap())
                .collect();
            assert_eq!(engines[1].transport().tiles(), rows);
            assert_eq!(
                engines[4].transport().tile_rows(),
                rows,
                "clamped to the pixels"
            );
            let mut a =
                Approximator::new(bands.clone(), vec![1.0; cols], channels, 6, policy).unwrap();
            let mut lighting: Vec<f32> = (0..cols * channels)
                .map(|_| rng.random_range(-1.0f32..1.0))
                .collect();
            for _ in 0..12 {
                for v in &mut lighting {
                    *v += rng.random_range(-0.5f32..0.5);
                }
                let update = a.step(&lighting).unwrap().clone();
                let bytes: Vec<usize> = engines
                    .iter_mut()
                    .map(|e| e.apply(&update).unwrap())
                    .collect();
                assert!(bytes.iter().all(|&b| b == bytes[0]));
                for e in &engines[1..] {
                    assert_eq!(
                        e.image(),
                        engines[0].image(),
                        "{policy:?}, {channels} channels"
                    );
                }
            }
        }
    }
}

#[test]
fn level_face_bands_drive_the_engine() {
    // 42 bands (level × face) of a 4 × 4 cube map: the dealer scales to them and the engine's
    // partial images stay consistent with the dense product.
    let layout = prt_wavelet::CubemapLayout::new(4).unwrap();
    let bands = layout.level_face_bands();
    let band_count = 6 * layout.band_count();
    let cols = layout.len();
    let mut rng = Pcg64::seed_from_u64(5);
    let oracle = DenseOracle::new(sparse_matrix(20, cols, 0.5, &mut rng), 1).unwrap();
    let t = SparseTransport::from_oracle(&oracle, 30, &NoProgress).unwrap();
    let deq = t.to_dense();
    let mut a = Approximator::new(
        bands,
        layout.area_weights().to_vec(),
        1,
        9,
        Policy::PerBand(BandStrategy::Dealer),
    )
    .unwrap();
    let mut engine = Relighter::new(t, 1, band_count).unwrap();
    let mut lighting: Vec<f32> = (0..cols).map(|_| rng.random_range(0.0f32..4.0)).collect();
    for _ in 0..30 {
        for v in &mut lighting {
            *v = (*v + rng.random_range(-0.3f32..0.3)).max(0.0);
        }
        let update = a.step(&lighting).unwrap().clone();
        assert_eq!(update.modes.len(), band_count);
        engine.apply(&update).unwrap();
        for r in 0..20 {
            let exact: f64 = (0..cols)
                .map(|j| deq[r * cols + j] as f64 * a.approximation()[j] as f64)
                .sum();
            assert!((engine.image()[r] as f64 - exact).abs() <= 1e-3 * (1.0 + exact.abs()));
        }
    }
}

#[test]
fn bad_input_and_cancellation() {
    let rgb = DenseOracle::new(Array2::zeros((4, 6)), 3).unwrap();
    assert!(matches!(
        SparseTransport::from_oracle(&rgb, 2, &NoProgress),
        Err(WaveletError::Invalid { .. })
    ));
    assert_eq!(
        SparseTransport::from_oracle(&NanRow, 2, &NoProgress),
        Err(WaveletError::NonFinite {
            what: "transport",
            index: 3 * 5 + 2
        })
    );
    let oracle = DenseOracle::new(Array2::ones((100, 4)), 1).unwrap();
    let progress = AtomicProgress::cancel_after(10);
    assert_eq!(
        SparseTransport::from_oracle(&oracle, 2, &progress),
        Err(WaveletError::Cancelled)
    );
    let t = SparseTransport::from_oracle(&oracle, 2, &NoProgress).unwrap();
    assert_eq!(t.nnz(), 200);
    let mut engine = Relighter::new(t, 1, 2).unwrap();
    let mut a =
        Approximator::new(vec![0, 1, 2, 0], vec![1.0; 4], 1, 2, Policy::Incremental).unwrap();
    let update = a.step(&[1.0, 2.0, 3.0, 4.0]).unwrap().clone();
    // Three bands in the update, two in the engine.
    assert!(matches!(
        engine.apply(&update),
        Err(WaveletError::LengthMismatch { .. })
    ));
    assert!(matches!(
        Relighter::new(
            SparseTransport::from_oracle(&oracle, 1, &NoProgress).unwrap(),
            0,
            1
        ),
        Err(WaveletError::Invalid { .. })
    ));
}

/// A 4 × 5 oracle whose row 3 holds a NaN in column 2.
struct NanRow;

impl MatrixOracle for NanRow {
    fn rows(&self) -> usize {
        4
    }
    fn cols(&self) -> usize {
        5
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.fill(1.0);
        if i == 3 {
            out[2] = f32::NAN;
        }
        Ok(())
    }
    fn eval_col(&self, _j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.fill(1.0);
        Ok(())
    }
    fn elements_evaluated(&self) -> u64 {
        0
    }
}

#[test]
fn sparse_bands_scatter_directly_and_threads_never_change_the_image() {
    // 300 pixels, 2 entries kept per row: a column holds ~15 entries, so single-term bands
    // scatter straight into the images while many-term bands go through the scratch tile.
    // Every tiling and every thread count must give bit-identical images, and the partial
    // images must be the bands' own products.
    let mut rng = Pcg64::seed_from_u64(11);
    let (rows, cols) = (300, 40);
    let oracle = DenseOracle::new(sparse_matrix(rows, cols, 0.3, &mut rng), 1).unwrap();
    let t = SparseTransport::from_oracle(&oracle, 2, &NoProgress).unwrap();
    let deq = t.to_dense();
    let (sizes, sparse_size) = (t.column_bytes(0), 4 * rows / 4);
    assert!(sizes < sparse_size, "column 0 is sparse: {sizes} bytes");
    // Band 0 holds one column (direct scatter), band 1 all the others (scratch tile).
    let bands: Vec<u8> = (0..cols).map(|j| u8::from(j > 0)).collect();
    let pools: Vec<rayon::ThreadPool> = [1, 3]
        .iter()
        .map(|&n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        })
        .collect();
    for channels in [1, 3] {
        let mut engines: Vec<(usize, Relighter)> = [(0, rows), (0, 7), (1, 7), (1, 64)]
            .iter()
            .map(|&(pool, n)| {
                (
                    pool,
                    Relighter::new(t.clone().with_tile_rows(n), channels, 2).unwrap(),
                )
            })
            .collect();
        let mut a = Approximator::new(
            bands.clone(),
            vec![1.0; cols],
            channels,
            5,
            Policy::PerBand(BandStrategy::Exhaustive),
        )
        .unwrap();
        let mut lighting: Vec<f32> = (0..cols * channels)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect();
        for _ in 0..10 {
            for v in &mut lighting {
                *v += rng.random_range(-0.5f32..0.5);
            }
            let update = a.step(&lighting).unwrap().clone();
            for (pool, e) in &mut engines {
                pools[*pool].install(|| e.apply(&update)).unwrap();
            }
            for (_, e) in &engines[1..] {
                assert_eq!(e.image(), engines[0].1.image(), "{channels} channels");
            }
            let engine = &engines[3].1;
            let approx = a.approximation();
            for band in 0..2 {
                let partial = engine.partial_image(band).unwrap();
                for r in 0..rows {
                    for c in 0..channels {
                        let exact: f64 = (0..cols)
                            .filter(|&j| bands[j] as usize == band)
                            .map(|j| deq[r * cols + j] as f64 * approx[c * cols + j] as f64)
                            .sum();
                        let got = partial[r * channels + c] as f64;
                        assert!(
                            (got - exact).abs() <= 1e-4 * (1.0 + exact.abs()),
                            "band {band} pixel {r}: {got} vs {exact}"
                        );
                    }
                }
            }
        }
        assert!(engines[0].1.partial_image(2).is_err());
    }
}
