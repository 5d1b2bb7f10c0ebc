//! prt-texture: container size/error per encoding for an MBD-sized model (printed table), then
//! criterion timings of KTX2 write/read against a plain copy of the same bytes, Radiance HDR
//! decoding against the `image` crate, and quantisation throughput.
//!
//! `cargo bench -p prt-benches --bench texture`
use std::hint::black_box;
use std::io::Cursor;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use prt_benches::{Table, fmt_duration, median_time};
use prt_texture::container::{ArrayLayout, Container, GridArray, LoadedContainer};
use prt_texture::hdr::decode_hdr;
use prt_texture::{Encoding, Ktx2Texture, Limits, PixelFormat, Shape, quantize};
use rand::{Rng, SeedableRng};

fn random(n: usize, seed: u64, scale: f32) -> Vec<f32> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(-scale..scale)).collect()
}

/// MBD production-like sizes: 32³ coefficient grid of rank 16, 5³ basis grid of 324 x 16.
fn container_table() {
    let (l, d) = (16usize, 324usize);
    let coeff = GridArray::new([32, 32, 32], l, random(32 * 32 * 32 * l, 1, 3.0)).expect("finite");
    let basis = GridArray::new([5, 5, 5], d * l, random(125 * d * l, 2, 0.2)).expect("finite");
    let voxels = 32u64 * 32 * 32;
    let mut table = Table::new(&[
        "encoding (coefficients / basis)",
        "bytes written",
        "bytes per voxel",
        "encode",
        "decode",
        "max |err| / range",
        "RMSE / range",
    ]);
    for enc in [
        Encoding::F32,
        Encoding::F16,
        Encoding::Unorm16,
        Encoding::Unorm8,
        Encoding::Snorm8,
    ] {
        let mut c = Container::default();
        c.arrays.push((
            "coefficients".into(),
            coeff.clone(),
            enc,
            ArrayLayout::Volume,
        ));
        c.arrays
            .push(("basis".into(), basis.clone(), enc, ArrayLayout::Rows));
        let encode = median_time(5, || c.encode().expect("encodes"));
        let (manifest, files) = c.encode().expect("encodes");
        let json = manifest.to_json().expect("json");
        let total: u64 = files.iter().map(|(_, b)| b.len() as u64).sum::<u64>() + json.len() as u64;
        let load = || {
            LoadedContainer::decode(&json, &Limits::default(), |name| {
                Ok(files
                    .iter()
                    .find(|(n, _)| n == name)
                    .expect("file")
                    .1
                    .clone())
            })
            .expect("decodes")
        };
        let decode = median_time(5, load);
        let back = load();
        let (mut max_err, mut sq, mut n) = (0f64, 0f64, 0usize);
        for (orig, (_, got), range) in [
            (&coeff, &back.arrays[0], 6.0),
            (&basis, &back.arrays[1], 0.4),
        ] {
            for (a, b) in orig.data.iter().zip(&got.data) {
                let e = f64::from((a - b).abs()) / range;
                max_err = max_err.max(e);
                sq += e * e;
                n += 1;
            }
        }
        table.row(vec![
            format!("{enc:?}"),
            total.to_string(),
            format!("{:.2}", total as f64 / voxels as f64),
            fmt_duration(encode),
            fmt_duration(decode),
            format!("{max_err:.2e}"),
            format!("{:.2e}", (sq / n as f64).sqrt()),
        ]);
    }
    println!("\nContainer for a 32^3 x L=16 coefficient grid + 5^3 x (324 x 16) basis grid\n");
    println!("{}", table.markdown());
    let _ = table.write_csv_if_requested("texture_container");
}

fn ktx2_and_quant(c: &mut Criterion) {
    container_table();
    let shape = Shape::d3(64, 64, 64);
    let values = random(64 * 64 * 64 * 4, 3, 100.0);
    let texture = Ktx2Texture::from_f32(
        PixelFormat::R16G16B16A16Sfloat,
        shape,
        std::slice::from_ref(&values),
    )
    .expect("encodes");
    let bytes = texture.to_bytes().expect("serialises");
    let mut group = c.benchmark_group("ktx2_rgba16f_64cubed");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.bench_function("memcpy_same_bytes", |b| b.iter(|| black_box(bytes.clone())));
    group.bench_function("write", |b| {
        b.iter(|| black_box(texture.to_bytes().expect("serialises")))
    });
    group.bench_function("read", |b| {
        b.iter(|| black_box(Ktx2Texture::from_bytes(&bytes, &Limits::default()).expect("parses")))
    });
    group.bench_function("ktx2_crate_parse_and_copy", |b| {
        b.iter(|| {
            let r = ktx2::Reader::new(&bytes[..]).expect("parses");
            black_box(r.levels().map(|l| l.data.to_vec()).collect::<Vec<_>>())
        })
    });
    group.finish();

    let mut group = c.benchmark_group("quantize_1M_values");
    let v = random(1 << 20, 4, 10.0);
    let nonneg: Vec<f32> = v[..v.len() / 3 * 3].iter().map(|x| x.abs()).collect();
    group.throughput(Throughput::Elements(v.len() as u64));
    for enc in [Encoding::F16, Encoding::Unorm16, Encoding::Snorm8] {
        group.bench_function(format!("{enc:?}"), |b| {
            b.iter(|| black_box(quantize(&v, 4, enc).expect("finite")))
        });
    }
    group.bench_function("Rgb9e5", |b| {
        b.iter(|| black_box(quantize(&nonneg, 3, Encoding::Rgb9e5).expect("finite")))
    });
    group.finish();
}

fn hdr(c: &mut Criterion) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/envmaps/venice_sunset_1k.hdr");
    let Ok(bytes) = std::fs::read(&path) else {
        eprintln!("skipping HDR benchmark: {} is absent", path.display());
        return;
    };
    let mut group = c.benchmark_group("hdr_decode_venice_sunset_1k");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.bench_function("prt_texture", |b| {
        b.iter(|| black_box(decode_hdr(&bytes, &Limits::default()).expect("decodes")))
    });
    group.bench_function("image_crate", |b| {
        b.iter(|| {
            use image::ImageDecoder;
            let d = image::codecs::hdr::HdrDecoder::new(Cursor::new(&bytes[..])).expect("header");
            let mut buf = vec![0u8; d.total_bytes() as usize];
            d.read_image(&mut buf).expect("decodes");
            black_box(buf)
        })
    });
    group.finish();
}

criterion_group!(benches, ktx2_and_quant, hdr);
criterion_main!(benches);
