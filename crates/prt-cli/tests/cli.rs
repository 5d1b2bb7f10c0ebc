//! End-to-end tests of the `prt` binary: a small bake whose report must show a working pipeline,
//! and the one-line errors of bad input.

use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::{assert_clean_failure, prt, scratch, stderr};

#[test]
fn small_cornell_bake_writes_a_consistent_report() {
    let out_dir = scratch("bake");
    bake_small_cornell(&out_dir);
    for file in [
        "report.md",
        "report.json",
        "loss.png",
        "comparison.png",
        "seams_mbd.png",
        "seam_profile.png",
        "mbd/manifest.json",
        "mbd/coefficients.ktx2",
        "mbd/basis.ktx2",
        "volumes/manifest.json",
        "volumes/reference.0.ktx2",
        "volumes/cpca.8.ktx2",
    ] {
        assert!(out_dir.join(file).is_file(), "missing {file}");
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("report.json")).expect("report.json"))
            .expect("valid JSON");
    let methods = report["methods"].as_array().expect("methods");
    let get = |name: &str| {
        methods
            .iter()
            .find(|m| m["method"].as_str().is_some_and(|n| n.starts_with(name)))
            .unwrap_or_else(|| panic!("no {name} row"))
    };
    let (mbd, written, bpca) = (get("MBD"), get("MBD as written"), get("BPCA"));
    let rel = |m: &serde_json::Value| m["relative_mse"].as_f64().expect("relative_mse");
    // A broken tracer, solver or writer shows up as a large error; these bounds hold with margin.
    assert!(rel(mbd) < 0.05, "MBD relative MSE {}", rel(mbd));
    assert!(
        rel(written) < rel(mbd) * 1.5 + 1e-4,
        "quantisation lost too much: {} vs {}",
        rel(written),
        rel(mbd)
    );
    // At this tiny size Monte Carlo noise dominates every method's error, so the comparison with
    // BPCA is loose; a broken solver is far outside it.
    assert!(
        rel(mbd) <= rel(bpca) * 1.5,
        "MBD {} much worse than BPCA {}",
        rel(mbd),
        rel(bpca)
    );
    // MBD is continuous: its error does not jump at basis-cell boundaries.
    let seam = |m: &serde_json::Value| m["seam_ratio"].as_f64().expect("seam_ratio");
    assert!(
        (0.8..1.2).contains(&seam(mbd)),
        "MBD seam ratio {}",
        seam(mbd)
    );
    // Without the reference's noise the seams are plain: BPCA's basis jumps at its block edges,
    // MBD's moves continuously.
    let denoised = |m: &serde_json::Value| {
        m["denoised_seam_ratio"]
            .as_f64()
            .expect("denoised_seam_ratio")
    };
    assert!(
        denoised(bpca) > 1.5 * denoised(mbd),
        "denoised seam ratio: BPCA {} vs MBD {}",
        denoised(bpca),
        denoised(mbd)
    );
    assert!(written["bytes_per_voxel"].as_f64().expect("bytes") > 0.0);
    // Image metrics head the report, per view, and the ranking it prints follows ꟻLIP.
    let images = &report["image_metrics"];
    let views = images["views"].as_array().expect("image metric views");
    assert!(views.len() >= 2, "the automatic views at least");
    let mut means: Vec<(String, f64)> = views[0]["methods"]
        .as_array()
        .expect("methods")
        .iter()
        .map(|m| {
            let key = m["method"].as_str().expect("key").to_string();
            let flips: Vec<f64> = views
                .iter()
                .flat_map(|v| v["methods"].as_array().expect("methods"))
                .filter(|n| n["method"] == m["method"])
                .map(|n| n["flip"].as_f64().expect("flip"))
                .collect();
            assert!(flips.iter().all(|f| (0.0..=1.0).contains(f)), "{flips:?}");
            (key, flips.iter().sum::<f64>() / flips.len() as f64)
        })
        .collect();
    means.sort_by(|a, b| a.1.total_cmp(&b.1));
    let ranking: Vec<&str> = images["ranking_by_flip"]
        .as_array()
        .expect("ranking")
        .iter()
        .map(|r| r["method"].as_str().expect("method"))
        .collect();
    let expected: Vec<&str> = means.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(ranking, expected);
    let md = std::fs::read_to_string(out_dir.join("report.md")).expect("report.md");
    let eye = md
        .find("## What the eye sees")
        .expect("image metrics section");
    assert!(eye < md.find("## Compression").expect("compression section"));
    let sentence = md[eye..]
        .lines()
        .find(|l| l.contains("Ranked by mean"))
        .expect("ranking sentence");
    let positions: Vec<usize> = expected
        .iter()
        .map(|k| {
            sentence
                .find(&format!("{} (", k.to_uppercase()))
                .unwrap_or_else(|| panic!("{k} not ranked in {sentence}"))
        })
        .collect();
    assert!(positions.windows(2).all(|w| w[0] < w[1]), "{sentence}");
    let losses = report["mbd"]["loss"].as_array().expect("loss history");
    assert!(!losses.is_empty());
    // The inspect command reads back what bake wrote.
    let inspect = prt(&["inspect", out_dir.join("mbd").to_str().expect("utf-8")]);
    assert!(inspect.status.success(), "{}", stderr(&inspect));
    let printed = String::from_utf8_lossy(&inspect.stdout);
    assert!(printed.contains("array coefficients"), "{printed}");
    // A container folder is also read back as a model.
    assert!(
        printed.contains("model: MBD rank 4, dimension 324"),
        "{printed}"
    );
    let inspect = prt(&[
        "inspect",
        out_dir.join("mbd/basis.ktx2").to_str().expect("utf-8"),
    ]);
    assert!(inspect.status.success(), "{}", stderr(&inspect));
}

#[test]
fn bad_input_gives_one_line_errors() {
    let dir = scratch("bad");
    let path = |name: &str| dir.join(name).to_str().expect("utf-8").to_string();
    assert_clean_failure(&prt(&["bake", &path("missing.gltf")]), "does not exist");

    std::fs::write(dir.join("not.gltf"), "this is not glTF").expect("write");
    assert_clean_failure(
        &prt(&["bake", &path("not.gltf"), "--out", &path("o1")]),
        "cannot load",
    );

    std::fs::write(
        dir.join("empty.gltf"),
        r#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[]}],"scene":0}"#,
    )
    .expect("write");
    assert_clean_failure(
        &prt(&["bake", &path("empty.gltf"), "--out", &path("o2")]),
        "no triangles",
    );

    write_points_gltf(&dir.join("points.gltf"));
    assert_clean_failure(
        &prt(&["bake", &path("points.gltf"), "--out", &path("o3")]),
        "no triangles",
    );

    assert_clean_failure(&prt(&["bake", "--res", "0"]), "--res");
    assert_clean_failure(&prt(&["bake", "--rank", "400"]), "--rank");
    std::fs::write(dir.join("a-file"), "").expect("write");
    assert_clean_failure(
        &prt(&["bake", "--res", "4", "--out", &path("a-file/sub")]),
        "output folder",
    );

    assert_clean_failure(&prt(&["encode", &path("missing.hdr")]), "does not exist");
    assert_clean_failure(&prt(&["inspect", &path("not.gltf")]), "unknown file type");
}

/// A one-triangle glTF whose primitive is drawn as points (mode 0): not bakeable.
fn write_points_gltf(path: &Path) {
    let positions: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64(&positions)
    );
    let doc = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"mode":0}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,"uri":"{uri}"}}]}}"#
    );
    std::fs::write(path, doc).expect("write glTF");
}

fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for i in 0..4 {
            if i <= chunk.len() {
                s.push(TABLE[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

#[test]
fn encode_fits_a_constant_map_exactly_and_inspect_reads_it() {
    let dir = scratch("encode");
    let map = dir.join("constant.hdr");
    let (w, h, c) = (32u32, 16u32, [0.5f32, 1.0, 2.0]);
    let pixels: Vec<f32> = (0..w * h).flat_map(|_| c).collect();
    let image = prt_texture::hdr::RgbImage::new(w, h, pixels).expect("image");
    prt_texture::hdr::write_hdr(&map, &image).expect("write hdr");
    let map_arg = map.to_str().expect("utf-8");

    let encode = |basis: &str, method: &str| -> (f64, Vec<f64>) {
        let out = prt(&[
            "encode",
            map_arg,
            "--basis",
            basis,
            "--method",
            method,
            "--samples",
            "4000",
        ]);
        assert!(out.status.success(), "{basis} {method}: {}", stderr(&out));
        let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
        let first = doc["coefficients_rgb"][0]
            .as_array()
            .expect("rgb")
            .iter()
            .map(|v| v.as_f64().expect("f64"))
            .collect();
        (doc["rmse"].as_f64().expect("rmse"), first)
    };
    // A constant lies in the span of SH and of the ambient cube: least squares reproduces it
    // exactly, the Monte Carlo projection up to its quasi-random integration error.
    let scale = (4.0 * std::f64::consts::PI).sqrt();
    for (basis, method, bound) in [
        ("sh:3", "ls", 1e-4),
        ("sh:2", "projection", 1e-2),
        ("ambient-cube", "nnls", 1e-4),
    ] {
        let (rmse, first) = encode(basis, method);
        assert!(rmse < bound, "{basis} {method}: rmse {rmse}");
        if basis.starts_with("sh") {
            for k in 0..3 {
                assert!(
                    (first[k] / (c[k] as f64 * scale) - 1.0).abs() < bound,
                    "{basis}: DC {first:?}"
                );
            }
        }
    }
    // Twelve lobes of sharpness 6 cannot represent a constant (their sum ripples); the progressive
    // encoder must converge to the least-squares optimum over the same samples.
    let (ls, _) = encode("sg:12", "ls");
    let (progressive, _) = encode("sg:12", "progressive");
    assert!(ls > 0.05, "12 SG should not fit a constant exactly: {ls}");
    assert!(
        progressive <= ls * 1.01,
        "progressive {progressive} vs least squares {ls}"
    );
    let inspect = prt(&["inspect", map_arg]);
    assert!(inspect.status.success(), "{}", stderr(&inspect));
    assert!(String::from_utf8_lossy(&inspect.stdout).contains("32 x 16 RGB"));
}

/// A bake far over the memory budget is refused before anything is traced or written, with the
/// need, the budget and the largest resolution that fits (bakes that fit run under the default
/// budget in the other tests).
#[test]
fn an_oversized_bake_is_refused_before_it_starts() {
    let out_dir = scratch("too-large");
    let folder = out_dir.join("never");
    let out = prt(&[
        "bake",
        "--res",
        "1000",
        "--out",
        folder.to_str().expect("utf-8 temp path"),
    ]);
    assert_clean_failure(&out, "largest resolution that fits is");
    let line = stderr(&out);
    assert!(
        line.contains("needs about") && line.contains("budget"),
        "{line}"
    );
    assert!(
        !folder.exists(),
        "the refused bake created {}",
        folder.display()
    );
    let out = prt(&["bake", "--res", "8", "--max-memory", "12Q"]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("unknown unit"), "{}", stderr(&out));
}

/// `prt ARGS` with `RAYON_NUM_THREADS` set when `threads` is given.
fn prt_on_threads(args: &[&str], threads: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_prt"));
    command.args(args);
    if let Some(n) = threads {
        command.env("RAYON_NUM_THREADS", n);
    }
    command.output().expect("the prt binary runs")
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A small Cornell bake into `dir` (seconds in a debug build).
fn bake_small_cornell(dir: &Path) {
    let dir = dir.to_str().expect("utf-8 temp path");
    let out = prt(&[
        "bake",
        "--res",
        "12",
        "--rays",
        "96",
        "--cache-rays",
        "32",
        "--rank",
        "4",
        "--basis-nodes",
        "3",
        "--iterations",
        "24",
        "--out",
        dir,
    ]);
    assert!(out.status.success(), "bake failed: {}", stderr(&out));
}

fn prt_render(dir: &Path, extra: &[&str], out: &Path, threads: Option<&str>) -> Output {
    let mut args = vec!["render", dir.to_str().expect("utf-8"), "--size", "40"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", out.to_str().expect("utf-8")]);
    prt_on_threads(&args, threads)
}

/// `prt render` on a small Cornell bake: every method renders, the images are deterministic on
/// any thread count, and bad input gives one-line errors.
#[test]
fn every_method_of_a_cornell_bake_renders() {
    let dir = scratch("render");
    bake_small_cornell(&dir);
    for file in [
        "scene.mesh",
        "rendered.png",
        "render_mbd.png",
        "render_seams_bpca.png",
    ] {
        assert!(dir.join(file).is_file(), "the bake did not write {file}");
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).expect("report.json"))
            .expect("valid JSON");
    for key in ["mbd", "bpca", "cpca"] {
        let rmse = report["renders"]["rmse_vs_reference"][key].as_f64();
        assert!(rmse.is_some_and(|r| r > 0.0 && r < 0.1), "{key}: {rmse:?}");
    }

    for method in ["reference", "mbd", "bpca", "cpca"] {
        let png = dir.join(format!("{method}.png"));
        let out = prt_render(&dir, &["--method", method], &png, None);
        assert!(out.status.success(), "{method}: {}", stderr(&out));
        let image = image::open(&png).expect("a PNG").to_rgb8();
        assert_eq!(image.dimensions(), (40, 40));
        // The box's interior is lit: its centre is neither black nor white.
        let centre = image.get_pixel(20, 20).0;
        assert!(
            centre.iter().all(|&c| c > 20 && c < 250),
            "{method}: {centre:?}"
        );
        if method != "reference" {
            let text = stdout(&out);
            let percent: f64 = text
                .split("RMSE against the reference render: ")
                .nth(1)
                .and_then(|s| s.split(" (").nth(1))
                .and_then(|s| s.split(' ').next())
                .and_then(|s| s.parse().ok())
                .unwrap_or_else(|| panic!("no RMSE in {text:?}"));
            assert!(percent > 0.0 && percent < 15.0, "{method}: {percent} %");
        }
    }
    // --compare scores the render as the report does: ꟻLIP in (0, 1) against the reference.
    let out = prt_render(&dir, &["--compare"], &dir.join("compared.png"), None);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = stdout(&out);
    let flip: f64 = text
        .split("FLIP ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no FLIP in {text:?}"));
    assert!(flip > 0.0 && flip < 0.5, "FLIP {flip}");

    // Linear radiance in EXR: finite, non-negative, above 1 only where the light (emission 1)
    // or the sky (radiance about 1 to 1.6) shows.
    let exr = dir.join("mbd.exr");
    let out = prt_render(&dir, &["--rotate", "30"], &exr, None);
    assert!(out.status.success(), "{}", stderr(&out));
    let layers = prt_texture::exr_io::read_exr(&exr, &prt_texture::Limits::default()).expect("EXR");
    assert_eq!((layers[0].width, layers[0].height), (40, 40));
    assert!(layers[0].data.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(
        layers[0].data.iter().any(|&v| v >= 1.0),
        "no emitter or sky pixel"
    );
    let mean = layers[0].data.iter().sum::<f32>() / layers[0].data.len() as f32;
    assert!(mean > 0.05 && mean < 1.0, "mean radiance {mean}");

    // The same image on one thread and on several. The default sky is symmetric about +Y, so a
    // rotation about +Y leaves it unchanged; another exposure does not.
    let one = dir.join("one.png");
    let many = dir.join("many.png");
    let rotated = dir.join("rotated.png");
    let brighter = dir.join("brighter.png");
    for (path, threads, rotate, exposure) in [
        (&one, "1", "0", "1.5"),
        (&many, "3", "0", "1.5"),
        (&rotated, "3", "90", "1.5"),
        (&brighter, "3", "0", "2"),
    ] {
        let flags = ["--rotate", rotate, "--exposure", exposure];
        let out = prt_render(&dir, &flags, path, Some(threads));
        assert!(out.status.success(), "{}", stderr(&out));
    }
    let bytes = |p: &Path| std::fs::read(p).expect("read");
    assert!(
        bytes(&one) == bytes(&many),
        "the image depends on the thread count"
    );
    assert!(
        bytes(&one) == bytes(&rotated),
        "a symmetric sky's rotation changed the image"
    );
    assert!(
        bytes(&one) != bytes(&brighter),
        "the exposure changed nothing"
    );

    let spare = dir.join("x.png");
    assert_clean_failure(
        &prt_render(&dir, &["--camera", "9"], &spare, None),
        "--camera 9",
    );
    assert_clean_failure(
        &prt_render(&dir, &[], &dir.join("x.jpg"), None),
        ".png or .exr",
    );
    assert_clean_failure(
        &prt_render(&dir, &["--sky", "sunset"], &spare, None),
        "--sky",
    );
    assert_clean_failure(&prt_render(&dir, &["--size", "0"], &spare, None), "--size");
    assert_clean_failure(
        &prt_render(&dir.join("nothing"), &[], &spare, None),
        "scene.mesh",
    );
    std::fs::remove_dir_all(dir.join("volumes")).expect("remove the kept volumes");
    assert_clean_failure(
        &prt_render(&dir, &["--method", "bpca"], &spare, None),
        "kept volumes",
    );
    // MBD needs only the container.
    assert!(
        prt_render(&dir, &["--method", "mbd"], &spare, None)
            .status
            .success()
    );
}
