"""PyWavelets reference timings for prt-wavelet's speed sweep (benches/src/bin/wavelet_speed.rs).

Prints one JSON object: median microseconds of
- haar_cubemap_us: 6 x 64 x 64 float32 faces, full 2D Haar decomposition + reconstruction,
  batched over the faces (pywt.wavedec2 / waverec2 with axes=(-2, -1), mode='periodization');
- db2_256_us: 256 float32 samples, full db2 periodization decomposition + reconstruction.
One thread (OPENBLAS/OMP set to 1 by the caller).
"""
import json
import time
import warnings

import numpy as np
import pywt

warnings.simplefilter("ignore")


def median_us(f, reps):
    f()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    times.sort()
    return times[len(times) // 2] * 1e6


rng = np.random.default_rng(1)
cube = rng.random((6, 64, 64), dtype=np.float32)
sig = rng.random(256).astype(np.float32)


def haar_roundtrip():
    c = pywt.wavedec2(cube, "haar", mode="periodization", axes=(-2, -1))
    return pywt.waverec2(c, "haar", mode="periodization", axes=(-2, -1))


def db2_roundtrip():
    c = pywt.wavedec(sig, "db2", mode="periodization", level=8)
    return pywt.waverec(c, "db2", mode="periodization")


assert np.allclose(haar_roundtrip(), cube, atol=1e-5)
assert np.allclose(db2_roundtrip(), sig, atol=1e-5)
print(json.dumps({
    "pywt_version": pywt.__version__,
    "haar_cubemap_us": median_us(haar_roundtrip, 2000),
    "db2_256_us": median_us(db2_roundtrip, 5000),
}))
