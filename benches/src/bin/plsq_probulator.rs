//! Probulator's radiance RMSE table and sample-count sweep, reproduced with prt-sphere and
//! prt-plsq (anchors in ../shared/design/anchors.md).
//!
//! Run: `cargo run --release -p prt-benches --bin plsq_probulator -- [--frame yup|zup] [--csv DIR]`
//!
//! Probulator's definitions, matched here: maps are 256×128 lat-long; SG fit input = Halton(2,3)
//! indices 1..N mapped `z = 1 − 2u`, `φ = 2πv`, value of the nearest texel (SH and ambient dice
//! project the whole map by texel solid angles, as Probulator's experiments do); reconstruction at
//! texel centres; error = sqrt of the per-pixel MSE averaged over RGB (unweighted by solid
//! angle; `prt_plsq::radiance_rmse`); SG radiance not clamped, SH and ambient dice clamped at
//! 0. Probulator works in its own frame (`prt_plsq::LatLongFrame::Probulator`: prt's frame
//! turned by π about +Y in kayru/Probulator; Z-up in troughton's fork with `--frame zup`):
//! samples, lobes and dice vertices live in that frame and are rotated into prt's lat-long
//! frame only to address texels.
use std::path::PathBuf;

use clap::Parser;
use glam::Vec3;
use prt_benches::{Table, envmap_names, load_envmap};
use prt_core::{NoProgress, SphericalBasis};
use prt_plsq::{
    Denominator, EncoderConfig, LatLongFrame, ProgressiveEncoder, Sweep, Update, radiance_rmse,
    reference, sample_nearest,
};
use prt_sphere::sampling::halton_sphere;
use prt_sphere::{AmbientDiceBezier, AmbientDiceSrbf, LatLongMap, SgBasis, ShBasis};

/// The map `name` of ../shared/envmaps at Probulator's 256×128, or why it cannot be read.
fn load_map(name: &str) -> Result<LatLongMap, String> {
    let map = load_envmap(name)?;
    let (w, h) = (map.width(), map.height());
    if (w, h) == (256, 128) {
        return Ok(map);
    }
    // Box-filter down to 256×128 (Probulator uses stb_image_resize; no anchors depend on this).
    let (fx, fy) = (w / 256, h / 128);
    let mut data = Vec::with_capacity(256 * 128 * 3);
    for y in 0..128 {
        for x in 0..256 {
            let mut acc = Vec3::ZERO;
            for dy in 0..fy {
                for dx in 0..fx {
                    acc += map.texel(x * fx + dx, y * fy + dy);
                }
            }
            data.extend_from_slice(&(acc / (fx * fy) as f32).to_array());
        }
    }
    LatLongMap::new(256, 128, data).map_err(|e| format!("{name}: {e}"))
}

struct Probe {
    map: LatLongMap,
    frame: LatLongFrame,
}

impl Probe {
    fn samples(&self, n: usize) -> (Vec<Vec3>, Vec<f32>) {
        let dirs = halton_sphere(n);
        let values = sample_nearest(&self.map, &dirs, self.frame);
        (dirs, values)
    }

    /// Probulator's radiance RMSE of `coeffs` (basis rows × RGB).
    fn rmse(&self, basis: &dyn SphericalBasis, coeffs: &[f32], clamp: bool) -> f64 {
        radiance_rmse(&self.map, basis, coeffs, clamp, self.frame).unwrap_or(f64::NAN)
    }

    /// LS of the whole map by texel solid angles and the basis' Gram matrix (Probulator's
    /// ambient dice fits).
    fn ls_from_map(&self, basis: &dyn SphericalBasis) -> Vec<f32> {
        reference::least_squares_map(basis, &self.map, self.frame)
            .unwrap_or_else(|_| vec![f32::NAN; 3 * basis.len()])
    }
}

fn progressive(basis: &SgBasis, cfg: EncoderConfig, dirs: &[Vec3], values: &[f32]) -> Vec<f32> {
    let mut enc = ProgressiveEncoder::new(basis, 3, cfg).expect("valid config");
    enc.add_samples(dirs, values, None, &NoProgress)
        .expect("finite samples");
    enc.coefficients().to_vec()
}

fn accel3() -> EncoderConfig {
    EncoderConfig {
        update: Update::Residual { acceleration: 3.0 },
        denominator: Denominator::LerpFromOne,
        sweep: Sweep::GaussSeidel,
        ..EncoderConfig::paper()
    }
}

/// Probulator's lat-long frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Frame {
    /// kayru/Probulator's frame (prt's turned by π about +Y).
    Yup,
    /// troughton's Z-up fork.
    Zup,
}

#[derive(Debug, Parser)]
#[command(about = "Probulator's radiance RMSE table and sample-count sweep, reproduced")]
struct Cli {
    /// The frame the samples, lobes and dice vertices live in.
    #[arg(long, value_enum, default_value = "yup")]
    frame: Frame,
    /// Folder for the tables as CSV (plsq_probulator_table.csv, plsq_probulator_sweep.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn main() {
    let cli = Cli::parse();
    let frame = match cli.frame {
        Frame::Zup => LatLongFrame::ProbulatorZUp,
        Frame::Yup => LatLongFrame::Probulator,
    };
    let (uffizi, wells) = match (load_map("probulator_uffizi"), load_map("probulator_wells")) {
        (Ok(uffizi), Ok(wells)) => (uffizi, wells),
        (Err(e), _) | (_, Err(e)) => {
            println!("skipping: {e} (shared data absent)");
            return;
        }
    };
    let anchors: [(&str, f64, f64); 12] = [
        ("SH L1 (4)", 3.39398, 0.48756),
        ("SH L2 (9)", 2.80398, 0.44933),
        ("SH L3 (16)", 2.29190, 0.42840),
        ("SH L4 (25)", 1.91908, 0.41911),
        ("SG naive projection", 3.13246, 0.47668),
        ("SG least squares", 2.50891, 0.46679),
        ("SG non-negative least squares", 2.58235, 0.47044),
        ("SG progressive (\"running average\")", 2.52161, 0.46680),
        ("SG progressive, non-negative", 2.58916, 0.47056),
        (
            "SG progressive, acceleration 3, lerp denominator, Gauss-Seidel",
            2.51117,
            0.46688,
        ),
        ("ambient dice, Bezier", 1.64126, 0.40822),
        ("ambient dice, SRBF", 2.40000, 0.44642),
    ];
    let probes = [Probe { map: uffizi, frame }, Probe { map: wells, frame }];
    let n = 20000;
    let sg = SgBasis::new(
        prt_sphere::spiral_axes(12),
        vec![6.0; 12],
        "SG 12 spiral λ=6",
    )
    .expect("valid lobes");
    let mut results = vec![[f64::NAN; 2]; anchors.len()];
    for (p, probe) in probes.iter().enumerate() {
        let (dirs, values) = probe.samples(n);
        for order in 2..=5 {
            let sh = ShBasis::new(order).expect("order >= 1");
            // Probulator's ExperimentSH projects the whole map by texel solid angles (not the
            // Halton samples); with an identity Gram this is that projection.
            results[order - 2][p] = probe.rmse(&sh, &probe.ls_from_map(&sh), true);
        }
        let naive = reference::naive_projection(
            &sg,
            &dirs,
            &values,
            3,
            reference::probulator_sg_naive_scale(6.0, 12),
        )
        .expect("samples");
        results[4][p] = probe.rmse(&sg, &naive, false);
        let ls = reference::least_squares_samples(&sg, &dirs, &values, 3).expect("nonsingular");
        results[5][p] = probe.rmse(&sg, &ls, false);
        let nn = reference::nnls_samples(&sg, &dirs, &values, 3).expect("nonsingular");
        results[6][p] = probe.rmse(&sg, &nn, false);
        let ra = progressive(
            &sg,
            EncoderConfig::probulator_running_average(),
            &dirs,
            &values,
        );
        results[7][p] = probe.rmse(&sg, &ra, false);
        let cfg = EncoderConfig {
            non_negative: true,
            ..EncoderConfig::probulator_running_average()
        };
        results[8][p] = probe.rmse(&sg, &progressive(&sg, cfg, &dirs, &values), false);
        results[9][p] = probe.rmse(&sg, &progressive(&sg, accel3(), &dirs, &values), false);
        let bezier = AmbientDiceBezier;
        results[10][p] = probe.rmse(&bezier, &probe.ls_from_map(&bezier), true);
        let srbf = AmbientDiceSrbf;
        results[11][p] = probe.rmse(&srbf, &probe.ls_from_map(&srbf), true);
    }
    let mut t = Table::new(&[
        "method",
        "uffizi (prt)",
        "uffizi (anchor)",
        "Δ",
        "wells (prt)",
        "wells (anchor)",
        "Δ",
    ]);
    for (r, (name, au, aw)) in results.iter().zip(anchors) {
        let fmt = |v: f64| {
            if v.is_nan() {
                "not implemented".to_string()
            } else {
                format!("{v:.5}")
            }
        };
        let rel = |v: f64, a: f64| {
            if v.is_nan() {
                "–".to_string()
            } else {
                format!("{:+.2}%", 100.0 * (v / a - 1.0))
            }
        };
        t.row(vec![
            name.into(),
            fmt(r[0]),
            format!("{au:.5}"),
            rel(r[0], au),
            fmt(r[1]),
            format!("{aw:.5}"),
            rel(r[1], aw),
        ]);
    }
    println!("Probulator radiance RMSE table (frame {frame:?}, N = {n} Halton samples)\n");
    println!("{}", t.markdown());
    if let Err(e) = t.write_csv(cli.csv.as_deref(), "plsq_probulator_table") {
        eprintln!("could not write the CSV: {e}");
    }

    // Sample-count sweep: 12 SG at λ = 8, first N Halton samples, LS vs progressive (acc. 3).
    let sg8 = SgBasis::new(
        prt_sphere::spiral_axes(12),
        vec![8.0; 12],
        "SG 12 spiral λ=8",
    )
    .expect("valid lobes");
    let counts = [32usize, 64, 128, 256, 512];
    let mut sweep = Table::new(&["map", "method", "N=32", "N=64", "N=128", "N=256", "N=512"]);
    sweep.row(
        [
            "wells (anchor)",
            "LS",
            "0.54256",
            "0.50935",
            "0.48103",
            "0.47863",
            "0.47586",
        ]
        .map(String::from)
        .to_vec(),
    );
    sweep.row(
        [
            "wells (anchor)",
            "progressive (acc. 3)",
            "0.56455",
            "0.51423",
            "0.48031",
            "0.48265",
            "0.47627",
        ]
        .map(String::from)
        .to_vec(),
    );
    for name in envmap_names() {
        let Ok(map) = load_map(&name) else { continue };
        let probe = Probe { map, frame };
        let (all_dirs, all_values) = probe.samples(*counts.last().unwrap_or(&512));
        let mut ls_row = vec![name.clone(), "LS".into()];
        let mut pr_row = vec![name, "progressive (acc. 3)".into()];
        for &c in &counts {
            let (d, v) = (&all_dirs[..c], &all_values[..3 * c]);
            let ls = reference::least_squares_samples(&sg8, d, v, 3);
            ls_row.push(ls.map_or("singular".into(), |x| {
                format!("{:.5}", probe.rmse(&sg8, &x, false))
            }));
            pr_row.push(format!(
                "{:.5}",
                probe.rmse(&sg8, &progressive(&sg8, accel3(), d, v), false)
            ));
        }
        sweep.row(ls_row);
        sweep.row(pr_row);
    }
    println!("Sample-count sweep (12 SG, λ = 8, first N Halton samples, radiance RMSE)\n");
    println!("{}", sweep.markdown());
    if let Err(e) = sweep.write_csv(cli.csv.as_deref(), "plsq_probulator_sweep") {
        eprintln!("could not write the CSV: {e}");
    }
}
