//! Write-then-read round trips driven by fuzz input: a KTX2 texture of any supported format,
//! shape and mip count (also parsed by the `ktx2` crate), a Radiance HDR image, and a container
//! array. What we write must read back to what was written (within the documented bounds).
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_texture::container::{
    ArrayLayout, BrickRequest, Container, GridArray, LoadedContainer, brick_grid, live_bricks,
};
use prt_texture::hdr::{RgbImage, decode_hdr, encode_hdr};
use prt_texture::{Encoding, Ktx2Texture, Limits, PixelFormat, Shape};

/// Maps fuzz bytes onto values every format accepts ([0, 1]), with exact dyadic fractions.
fn unit_values(bytes: &[u8], n: usize) -> Vec<f32> {
    (0..n).map(|i| f32::from(bytes.get(i % bytes.len().max(1)).copied().unwrap_or(0)) / 255.0).collect()
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 8 {
        return;
    }
    let (head, rest) = data.split_at(8);
    let dim = |b: u8| u32::from(b % 6) + 1;
    match head[0] % 3 {
        0 => {
            let format = PixelFormat::ALL[usize::from(head[1]) % PixelFormat::ALL.len()];
            let shape = match head[2] % 5 {
                0 => Shape::d2(dim(head[3]), dim(head[4])),
                1 => Shape::d3(dim(head[3]), dim(head[4]), dim(head[5])),
                2 => Shape::d2_array(dim(head[3]), dim(head[4]), dim(head[5])),
                3 => Shape::cube(dim(head[3])),
                _ => Shape { height: 0, ..Shape::d2(dim(head[3]), 1) },
            };
            let levels = 1 + u32::from(head[6]) % shape.max_levels();
            let values: Vec<Vec<f32>> = (0..levels)
                .map(|l| unit_values(rest, shape.level_texels(l).unwrap() as usize * format.channels()))
                .collect();
            let mut texture = Ktx2Texture::from_f32(format, shape, &values).unwrap();
            if let Ok(key) = std::str::from_utf8(&rest[..rest.len().min(12)]) {
                if !key.is_empty() && !key.contains('\0') {
                    texture.set_key(key, rest.to_vec());
                }
            }
            let bytes = texture.to_bytes().unwrap();
            let oracle = ktx2::Reader::new(&bytes[..]).expect("the ktx2 crate parses our output");
            for (ours, theirs) in texture.levels().iter().zip(oracle.levels()) {
                assert_eq!(ours.as_slice(), theirs.data);
            }
            let back = Ktx2Texture::from_bytes(&bytes, &Limits::small()).unwrap();
            assert_eq!(back, texture);
        }
        1 => {
            let (w, h) = (dim(head[1]) * 7, dim(head[2]));
            let n = (3 * w * h) as usize;
            let pixels: Vec<f32> = (0..n)
                .map(|i| {
                    let b = rest.get(i % rest.len().max(1)).copied().unwrap_or(0);
                    f32::from(b) * 2f32.powi(i32::from(head[3] % 40) - 20)
                })
                .collect();
            let image = RgbImage::new(w, h, pixels).unwrap();
            let back = decode_hdr(&encode_hdr(&image).unwrap(), &Limits::small()).unwrap();
            for (a, b) in image.data.chunks(3).zip(back.data.chunks(3)) {
                let bound = prt_texture::hdr::rgbe_error_bound(a[0].max(a[1]).max(a[2]));
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() <= bound, "{a:?} -> {b:?}");
                }
            }
        }
        _ => {
            let dims = [dim(head[1]), dim(head[2]), dim(head[3])];
            let channels = usize::from(head[4] % 9) + 1;
            let encoding = [Encoding::F32, Encoding::F16, Encoding::Unorm8, Encoding::Snorm8, Encoding::Unorm16, Encoding::Snorm16]
                [usize::from(head[5]) % 6];
            let n = dims.iter().product::<u32>() as usize * channels;
            let values = unit_values(rest, n).iter().map(|v| v * 200.0 - 100.0).collect();
            let array = GridArray::new(dims, channels, values).unwrap();
            let layout = [ArrayLayout::Volume, ArrayLayout::Atlas, ArrayLayout::Rows, ArrayLayout::Bricks]
                [usize::from(head[6]) % 4];
            let mut c = Container::default();
            c.arrays.push(("a".into(), array.clone(), encoding, layout));
            // Bricks of 1 to 4 cells; a node is live when its fuzz byte is odd.
            let size = u32::from(head[7] % 4) + 1;
            let live: Vec<bool> = (0..array.nodes()).map(|i| rest.get(i).is_some_and(|b| b & 1 == 1)).collect();
            c.bricks.insert("a".into(), BrickRequest { size, live_nodes: live.clone() });
            let (manifest, files) = c.encode().unwrap();
            let json = manifest.to_json().unwrap();
            let loaded = LoadedContainer::decode(&json, &Limits::small(), |name| {
                Ok(files.iter().find(|(n, _)| n == name).expect("a written file").1.clone())
            })
            .unwrap();
            let entry = &manifest.arrays[0];
            // Nodes outside a stored brick read as 0; the others as the dense layout would.
            let stored = live_bricks(dims, size, &live).unwrap();
            let grid = brick_grid(dims, size);
            let in_stored = |node: usize| {
                let p = [node % dims[0] as usize, node / dims[0] as usize % dims[1] as usize, node / (dims[0] * dims[1]) as usize];
                let b = [0, 1, 2].map(|a| (p[a] as u32 / size).min(grid[a] - 1) as usize);
                layout != ArrayLayout::Bricks || stored[b[0] + grid[0] as usize * (b[1] + grid[1] as usize * b[2])]
            };
            for (i, (x, y)) in array.data.iter().zip(&loaded.arrays[0].1.data).enumerate() {
                if !in_stored(i / channels) {
                    assert!(!live[i / channels] && *y == 0.0, "[{i}]: {y} outside the stored bricks");
                    continue;
                }
                let r = entry.range(i % channels);
                let bound = match encoding {
                    Encoding::F32 => 0.0,
                    Encoding::F16 => x.abs() * 2f32.powi(-11) + 2f32.powi(-25),
                    _ => r.half_step(encoding) + 4.0 * f32::EPSILON * (r.bias.abs() + r.scale),
                };
                assert!((x - y).abs() <= bound, "{encoding:?} [{i}]: {x} vs {y}");
            }
        }
    }
});
