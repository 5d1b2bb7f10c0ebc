//! `prt relight` end to end at a tiny size: the files it writes, the exact reference, and PBI
//! against NWA at equal terms on a turning map.

mod common;
use common::{assert_clean_failure, prt, scratch, stderr};

/// A 64 × 32 lat-long map: a dim sky, a bright patch and a small hot spot, so that a rotation
/// moves all-frequency light.
fn write_map(path: &std::path::Path) {
    let (w, h) = (64u32, 32u32);
    let mut data = Vec::with_capacity((3 * w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let mut v = [0.2f32, 0.25, 0.3];
            if (10..20).contains(&x) && (6..12).contains(&y) {
                v = [3.0, 2.5, 2.0];
            }
            if (40..42).contains(&x) && (10..12).contains(&y) {
                v = [40.0, 40.0, 40.0];
            }
            data.extend_from_slice(&v);
        }
    }
    let image = prt_texture::hdr::RgbImage {
        width: w,
        height: h,
        data,
    };
    prt_texture::hdr::write_hdr(path, &image).expect("write the map");
}

#[test]
fn tiny_cornell_relight_writes_frames_tables_and_a_plot() {
    let dir = scratch("relight");
    let map = dir.join("map.hdr");
    write_map(&map);
    let out = dir.join("out");
    let run = || {
        prt(&[
            "relight",
            "--envmap",
            map.to_str().unwrap(),
            "--size",
            "16",
            "--cube",
            "8",
            "--frames",
            "12",
            "--stop",
            "8",
            "--rotate",
            "4",
            "--method",
            "nwa,pbi,exact",
            "--terms",
            "20",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let first = run();
    assert!(first.status.success(), "{}", stderr(&first));
    for file in [
        "transport.prtpx",
        "preview.png",
        "frames.csv",
        "frames.md",
        "error.png",
        "frames/exact_0000.png",
        "frames/nwa20_0011.png",
        "frames/pbi20_0011.png",
    ] {
        assert!(out.join(file).is_file(), "missing {file}");
    }
    // The preview is an animated PNG: it has an acTL chunk.
    let preview = std::fs::read(out.join("preview.png")).unwrap();
    assert!(preview.windows(4).any(|w| w == b"acTL"));

    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    let errors = |method: &str| -> Vec<f64> {
        rows.iter()
            .filter(|r| r[0] == method)
            .map(|r| r[3].parse().unwrap())
            .collect()
    };
    let (exact, nwa, pbi) = (errors("exact"), errors("nwa20"), errors("pbi20"));
    assert_eq!((exact.len(), nwa.len(), pbi.len()), (12, 12, 12));
    assert!(exact.iter().all(|&e| e == 0.0));
    // At equal terms PBI's image error is at most NWA's, summed over the rotation and after
    // the stop; once the map stops, PBI converges while NWA stays where it is.
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    assert!(sum(&pbi[..8]) <= sum(&nwa[..8]), "{pbi:?} vs {nwa:?}");
    assert!(
        pbi[11] < 0.5 * nwa[11] && pbi[11] < 0.01,
        "{pbi:?} vs {nwa:?}"
    );

    // A second run reuses the transport.
    let second = run();
    assert!(second.status.success(), "{}", stderr(&second));
    assert!(stderr(&second).contains("reusing"), "{}", stderr(&second));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_relight_arguments_are_one_line_errors() {
    let dir = scratch("relight-bad");
    let out = dir.join("out");
    let missing = dir.join("missing.hdr");
    let o = out.to_str().unwrap();
    assert_clean_failure(
        &prt(&["relight", "--envmap", missing.to_str().unwrap(), "--out", o]),
        "does not exist",
    );
    let map = dir.join("map.hdr");
    write_map(&map);
    let m = map.to_str().unwrap();
    assert_clean_failure(
        &prt(&["relight", "--envmap", m, "--method", "svd", "--out", o]),
        "expected nwa, bi, pbi or exact",
    );
    assert_clean_failure(
        &prt(&[
            "relight", "--envmap", m, "--cube", "12", "--size", "8", "--out", o,
        ]),
        "cube",
    );
    let _ = std::fs::remove_dir_all(&dir);
}
