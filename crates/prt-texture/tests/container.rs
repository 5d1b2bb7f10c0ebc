//! The prt container: a synthetic MBD-shaped model (coefficient grid + basis grid) written and
//! read back within the quantisation bound, at the array level and at random points of the
//! reconstruction; bytes per voxel from the files actually written.

use proptest::prelude::*;
use prt_texture::container::{
    ArrayLayout, Container, GridArray, KernelDescription, LoadedContainer, MANIFEST_FILE,
    MBD_BASIS, MBD_COEFFICIENTS,
};
use prt_texture::{Encoding, Limits, TextureError};
use rand::{Rng, SeedableRng};

fn random_array(dims: [u32; 3], channels: usize, seed: u64, scale: f32) -> GridArray {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let n = dims.iter().product::<u32>() as usize * channels;
    GridArray::new(
        dims,
        channels,
        (0..n).map(|_| rng.random_range(-scale..scale)).collect(),
    )
    .unwrap()
}

/// A synthetic MBD model: f(x) = Σ_j c_j(x) B_j(x), both trilinearly interpolated on their grids
/// over the unit cube (D outputs, rank L).
struct Model {
    coeff: GridArray, // L channels
    basis: GridArray, // D·L channels, row-major D x L
    d: usize,
    l: usize,
}

fn trilinear(a: &GridArray, p: [f32; 3], out: &mut [f64]) {
    out.iter_mut().for_each(|v| *v = 0.0);
    let mut base = [0usize; 3];
    let mut frac = [0f32; 3];
    for k in 0..3 {
        let n = a.dims[k] as usize;
        let t = (p[k] * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        base[k] = (t.floor() as usize).min(n.saturating_sub(2));
        frac[k] = if n == 1 { 0.0 } else { t - base[k] as f32 };
    }
    for corner in 0..8 {
        let mut w = 1.0f64;
        let mut idx = [0usize; 3];
        for k in 0..3 {
            let hi = corner >> k & 1 == 1;
            idx[k] = (base[k] + hi as usize).min(a.dims[k] as usize - 1);
            w *= f64::from(if hi { frac[k] } else { 1.0 - frac[k] });
        }
        let node = idx[0] + a.dims[0] as usize * (idx[1] + a.dims[1] as usize * idx[2]);
        for (o, &v) in out
            .iter_mut()
            .zip(&a.data[node * a.channels..(node + 1) * a.channels])
        {
            *o += w * f64::from(v);
        }
    }
}

impl Model {
    fn eval(&self, p: [f32; 3]) -> Vec<f64> {
        let mut c = vec![0.0; self.l];
        let mut b = vec![0.0; self.d * self.l];
        trilinear(&self.coeff, p, &mut c);
        trilinear(&self.basis, p, &mut b);
        (0..self.d)
            .map(|i| (0..self.l).map(|j| b[i * self.l + j] * c[j]).sum())
            .collect()
    }
}

fn container(model: &Model, coeff_enc: Encoding, basis_enc: Encoding) -> Container {
    let mut c = Container::default();
    c.attributes.insert("dimension".into(), model.d.into());
    c.attributes.insert("rank".into(), model.l.into());
    for (name, a) in [(MBD_COEFFICIENTS, &model.coeff), (MBD_BASIS, &model.basis)] {
        c.kernels.insert(
            name.into(),
            KernelDescription {
                kind: "hat".into(),
                nodes: a.dims,
                domain_min: [0.0; 3],
                domain_max: [1.0; 3],
            },
        );
    }
    c.arrays.push((
        MBD_COEFFICIENTS.into(),
        model.coeff.clone(),
        coeff_enc,
        ArrayLayout::Volume,
    ));
    c.arrays.push((
        MBD_BASIS.into(),
        model.basis.clone(),
        basis_enc,
        ArrayLayout::Rows,
    ));
    c
}

fn temp_dir(tag: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("prt-texture-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn mbd_model_round_trips_within_the_quantisation_bound_at_random_points() {
    let (d, l) = (27, 6);
    let model = Model {
        coeff: random_array([9, 7, 5], l, 1, 2.0),
        basis: random_array([3, 3, 2], d * l, 2, 0.5),
        d,
        l,
    };
    let dir = temp_dir("mbd");
    let report = container(&model, Encoding::Unorm16, Encoding::Snorm8)
        .write(&dir)
        .unwrap();
    let loaded = LoadedContainer::read(&dir, &Limits::default()).unwrap();
    assert_eq!(loaded.manifest, report.manifest);
    let back = Model {
        coeff: loaded.array(MBD_COEFFICIENTS).unwrap().clone(),
        basis: loaded.array(MBD_BASIS).unwrap().clone(),
        d,
        l,
    };
    // Per-element bounds from the manifest's ranges.
    let entry = |name| {
        report
            .manifest
            .arrays
            .iter()
            .find(|e| e.name == name)
            .unwrap()
    };
    let (ce, be) = (entry(MBD_COEFFICIENTS), entry(MBD_BASIS));
    for (a, b, e) in [
        (&model.coeff, &back.coeff, ce),
        (&model.basis, &back.basis, be),
    ] {
        for (i, (x, y)) in a.data.iter().zip(&b.data).enumerate() {
            let r = e.range(i % a.channels);
            let bound = r.half_step(e.encoding) + 4.0 * f32::EPSILON * (r.bias.abs() + r.scale);
            assert!((x - y).abs() <= bound, "{}[{i}]: {x} vs {y}", e.name);
        }
    }
    // Reconstruction: |Σ b c - Σ b' c'| <= Σ |b||δc| + |δb||c'|, with |δ| the per-channel bounds
    // (trilinear weights sum to one, so interpolation does not grow them).
    let dc: Vec<f64> = (0..ce.channels)
        .map(|c| f64::from(ce.range(c).half_step(ce.encoding)) * 1.001 + 1e-6)
        .collect();
    let db: Vec<f64> = (0..be.channels)
        .map(|c| f64::from(be.range(c).half_step(be.encoding)) * 1.001 + 1e-6)
        .collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    for _ in 0..500 {
        let p = [
            rng.random::<f32>(),
            rng.random::<f32>(),
            rng.random::<f32>(),
        ];
        let (f, g) = (model.eval(p), back.eval(p));
        let mut c = vec![0.0; l];
        let mut b = vec![0.0; d * l];
        trilinear(&back.coeff, p, &mut c);
        trilinear(&model.basis, p, &mut b);
        for i in 0..d {
            let bound: f64 = (0..l)
                .map(|j| b[i * l + j].abs() * dc[j] + db[i * l + j] * c[j].abs())
                .sum();
            assert!(
                (f[i] - g[i]).abs() <= bound,
                "output {i} at {p:?}: {} vs {} (bound {bound})",
                f[i],
                g[i]
            );
        }
    }
    // Bytes per voxel counts what is on disk.
    let on_disk: u64 = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    assert_eq!(report.total_bytes, on_disk);
    assert_eq!(
        report.manifest_bytes,
        std::fs::metadata(dir.join(MANIFEST_FILE)).unwrap().len()
    );
    let voxels = 32u64 * 32 * 32;
    assert!((report.bytes_per_voxel(voxels) - on_disk as f64 / voxels as f64).abs() < 1e-12);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn float_encodings_are_exact_or_within_f16() {
    let a = random_array([4, 3, 2], 5, 3, 100.0);
    for (enc, layout) in [
        (Encoding::F32, ArrayLayout::Volume),
        (Encoding::F16, ArrayLayout::Rows),
    ] {
        let mut c = Container::default();
        c.arrays.push(("a".into(), a.clone(), enc, layout));
        let (manifest, files) = c.encode().unwrap();
        let json = manifest.to_json().unwrap();
        let loaded =
            LoadedContainer::decode(&json, &Limits::small(), |_| Ok(files[0].1.clone())).unwrap();
        for (x, y) in a.data.iter().zip(&loaded.arrays[0].1.data) {
            let bound = if enc == Encoding::F32 {
                0.0
            } else {
                x.abs() * 2f32.powi(-11)
            };
            assert!((x - y).abs() <= bound);
        }
    }
}

#[test]
fn only_normalised_encodings_store_ranges_and_version_1_identity_ranges_still_read() {
    let a = random_array([2, 3, 2], 6, 8, 4.0);
    for enc in [Encoding::F32, Encoding::F16, Encoding::Unorm16] {
        let mut c = Container::default();
        c.arrays
            .push(("a".into(), a.clone(), enc, ArrayLayout::Volume));
        let (manifest, files) = c.encode().unwrap();
        let json = String::from_utf8(manifest.to_json().unwrap()).unwrap();
        assert_eq!(
            json.contains("\"ranges\""),
            enc == Encoding::Unorm16,
            "{enc:?}"
        );
        if enc == Encoding::Unorm16 {
            continue;
        }
        // What version 1 wrote: identity maps for a float encoding.
        let mut v1 = manifest.clone();
        v1.version = 1;
        v1.arrays[0].ranges = vec![prt_texture::quant::ChannelRange::IDENTITY; 6];
        let load = |m: &prt_texture::container::Manifest| {
            LoadedContainer::decode(&m.to_json().unwrap(), &Limits::small(), |_| {
                Ok(files[0].1.clone())
            })
        };
        assert_eq!(load(&v1).unwrap().arrays, load(&manifest).unwrap().arrays);
        // A float encoding with a non-identity map is not something we wrote.
        let mut scaled = v1.clone();
        scaled.arrays[0].ranges[2].scale = 2.0;
        assert!(matches!(
            load(&scaled),
            Err(TextureError::Malformed {
                what: "manifest",
                ..
            })
        ));
    }
}

#[test]
fn rgb9e5_arrays_pack_three_channels_per_texel() {
    let mut a = random_array([2, 2, 2], 7, 4, 10.0);
    a.data.iter_mut().for_each(|v| *v = v.abs());
    let mut c = Container::default();
    c.arrays.push((
        "irr".into(),
        a.clone(),
        Encoding::Rgb9e5,
        ArrayLayout::Volume,
    ));
    let (manifest, files) = c.encode().unwrap();
    assert_eq!(manifest.arrays[0].groups(), 3);
    let t = prt_texture::Ktx2Texture::from_bytes(&files[0].1, &Limits::small()).unwrap();
    assert_eq!(
        (t.shape().width, t.shape().height, t.shape().depth),
        (2, 2, 6)
    );
    let json = manifest.to_json().unwrap();
    let loaded =
        LoadedContainer::decode(&json, &Limits::small(), |_| Ok(files[0].1.clone())).unwrap();
    for (node, back) in a.data.chunks(7).zip(loaded.arrays[0].1.data.chunks(7)) {
        for g in 0..3 {
            let group = &node[3 * g..(3 * g + 3).min(7)];
            let max = group.iter().fold(0f32, |m, &v| m.max(v));
            for (k, &x) in group.iter().enumerate() {
                assert!((x - back[3 * g + k]).abs() <= prt_texture::quant::rgb9e5_error_bound(max));
            }
        }
    }
}

#[test]
fn one_channel_arrays_use_one_channel_textures_where_the_encoding_has_one() {
    let a = random_array([3, 2, 2], 1, 9, 1.0);
    for (encoding, format, single) in [
        (Encoding::F32, prt_texture::PixelFormat::R32Sfloat, true),
        (Encoding::F16, prt_texture::PixelFormat::R16Sfloat, true),
        (Encoding::Unorm8, prt_texture::PixelFormat::R8Unorm, true),
        (
            Encoding::Unorm16,
            prt_texture::PixelFormat::R16G16B16A16Unorm,
            false,
        ),
    ] {
        let mut c = Container::default();
        c.arrays
            .push(("mask".into(), a.clone(), encoding, ArrayLayout::Volume));
        let (mut manifest, files) = c.encode().unwrap();
        assert_eq!(manifest.arrays[0].single_channel, single, "{encoding:?}");
        let t = prt_texture::Ktx2Texture::from_bytes(&files[0].1, &Limits::small()).unwrap();
        assert_eq!(t.format(), format, "{encoding:?}");
        let json = manifest.to_json().unwrap();
        let loaded =
            LoadedContainer::decode(&json, &Limits::small(), |_| Ok(files[0].1.clone())).unwrap();
        for (x, y) in a.data.iter().zip(&loaded.arrays[0].1.data) {
            assert!(
                (x - y).abs() <= 2.0 / 255.0 * 2.0,
                "{encoding:?}: {x} read as {y}"
            );
        }
        // A manifest that disagrees with the file's format is refused.
        manifest.arrays[0].single_channel = !single;
        let json = manifest.to_json().unwrap();
        assert!(
            LoadedContainer::decode(&json, &Limits::small(), |_| Ok(files[0].1.clone())).is_err(),
            "{encoding:?}"
        );
    }
}

#[test]
fn mismatched_or_foreign_textures_are_rejected() {
    let mut c = Container::default();
    c.arrays.push((
        "a".into(),
        random_array([2, 2, 2], 4, 5, 1.0),
        Encoding::Unorm8,
        ArrayLayout::Volume,
    ));
    c.arrays.push((
        "b".into(),
        random_array([2, 2, 2], 4, 6, 1.0),
        Encoding::Unorm8,
        ArrayLayout::Volume,
    ));
    let (manifest, files) = c.encode().unwrap();
    let json = manifest.to_json().unwrap();
    // Same shape and format but the embedded entry names the other array.
    let swapped = LoadedContainer::decode(&json, &Limits::small(), |f| {
        Ok(files.iter().find(|(n, _)| n != f).unwrap().1.clone())
    });
    assert!(
        matches!(
            swapped,
            Err(TextureError::Malformed {
                what: "container texture",
                ..
            })
        ),
        "{swapped:?}"
    );
    let missing = LoadedContainer::decode(&json, &Limits::small(), |f| {
        Err(TextureError::Malformed {
            what: "test",
            why: f.to_owned(),
        })
    });
    assert!(missing.is_err());
    // Duplicate names and bad names are refused when encoding.
    let mut dup = c.clone();
    dup.arrays[1].0 = "a".into();
    assert!(dup.encode().is_err());
    let mut bad = c.clone();
    bad.arrays[0].0 = "../x".into();
    assert!(bad.encode().is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn any_grid_array_round_trips(
        dims in prop::array::uniform3(1u32..5),
        channels in 1usize..11,
        which in 0usize..6,
        layout in 0usize..3,
        seed in any::<u64>(),
    ) {
        let enc = [Encoding::F32, Encoding::F16, Encoding::Unorm8, Encoding::Snorm8, Encoding::Unorm16, Encoding::Snorm16][which];
        let a = random_array(dims, channels, seed, 50.0);
        let mut c = Container::default();
        let layout = [ArrayLayout::Volume, ArrayLayout::Atlas, ArrayLayout::Rows][layout];
        c.arrays.push(("x".into(), a.clone(), enc, layout));
        let (manifest, files) = c.encode().unwrap();
        let loaded = LoadedContainer::decode(&manifest.to_json().unwrap(), &Limits::small(), |_| Ok(files[0].1.clone())).unwrap();
        let e = &manifest.arrays[0];
        for (i, (x, y)) in a.data.iter().zip(&loaded.arrays[0].1.data).enumerate() {
            let r = e.range(i % channels);
            let bound = match enc {
                Encoding::F32 => 0.0,
                Encoding::F16 => x.abs() * 2f32.powi(-11) + 2f32.powi(-25),
                _ => r.half_step(enc) + 4.0 * f32::EPSILON * (r.bias.abs() + r.scale),
            };
            prop_assert!((x - y).abs() <= bound, "{:?} {:?} [{}]: {} vs {}", enc, layout, i, x, y);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The atlas holds every group, has no empty layer of tiles and stays near a cube.
    #[test]
    fn atlas_tiles_hold_every_group_compactly(
        dims in prop::array::uniform3(1u32..40),
        groups in 1usize..3000,
    ) {
        let [tx, ty, tz] = prt_texture::container::atlas_tiles(dims, groups).map(|t| t as usize);
        prop_assert!(tx >= 1 && ty >= 1 && tz >= 1);
        prop_assert!(tx * ty * tz >= groups && tx * ty * (tz - 1) < groups);
        let sides = [tx * dims[0] as usize, ty * dims[1] as usize, tz * dims[2] as usize];
        let texels = (groups * dims.iter().map(|&d| d as usize).product::<usize>()) as f64;
        let longest = *sides.iter().max().unwrap() as f64;
        // Within a tile's side (plus a tile or two) of the cube root.
        let tile = *dims.iter().max().unwrap() as f64;
        prop_assert!(longest <= 2.0 * texels.cbrt() + 2.0 * tile, "{sides:?} for {groups} tiles of {dims:?}");
    }
}

/// Group `g` of node `(i, j, k)` is texel `(tx·nx + i, ty·ny + j, tz·nz + k)` of its tile.
#[test]
fn atlas_texels_sit_in_their_tiles() {
    let (dims, channels) = ([3u32, 2, 4], 4 * 7);
    let nodes = 24;
    // Value = group · 1000 + node, one value per group (the other three channels 0).
    let data: Vec<f32> = (0..nodes)
        .flat_map(|n| {
            (0..channels).map(move |c| {
                if c % 4 == 0 {
                    (c / 4 * 1000 + n) as f32
                } else {
                    0.0
                }
            })
        })
        .collect();
    let mut c = Container::default();
    c.arrays.push((
        "x".into(),
        GridArray::new(dims, channels, data).unwrap(),
        Encoding::F32,
        ArrayLayout::Atlas,
    ));
    let (manifest, files) = c.encode().unwrap();
    let entry = &manifest.arrays[0];
    let tiles = entry.tiles.unwrap();
    let texture = prt_texture::Ktx2Texture::from_bytes(&files[0].1, &Limits::small()).unwrap();
    let shape = texture.shape();
    assert_eq!(
        [shape.width, shape.height, shape.depth],
        [0, 1, 2].map(|a| dims[a] * tiles[a])
    );
    let texels = texture.level_f32(0).unwrap();
    for g in 0..7 {
        let [tx, ty, tz] = entry.tile_of(g).unwrap();
        for n in 0..nodes {
            let (i, j, k) = (n % 3, n / 3 % 2, n / 6);
            let x = tx as usize * 3 + i;
            let y = ty as usize * 2 + j;
            let z = tz as usize * 4 + k;
            let at = x + shape.width as usize * (y + shape.height as usize * z);
            assert_eq!(texels[4 * at], (g * 1000 + n) as f32, "group {g} node {n}");
        }
    }
    assert_eq!(entry.tile_of(7), None);
}
