"""Generates the PyWavelets reference vectors used by prt-wavelet's tests.

Run from this folder: `python3 gen_pywt.py` (PyWavelets 1.8, numpy). Writes pywt_vectors.json.
The Haar 2D arrays are laid out like prt-wavelet's non-standard decomposition: the scaling
coefficient at (0, 0); at each level of size s the block x in [s, 2s), y in [0, s) holds the
left-minus-right detail (pywt's cV), x in [0, s), y in [s, 2s) the top-minus-bottom detail (cH)
and x, y in [s, 2s) the diagonal detail (cD).
"""
import json
import warnings

import numpy as np
import pywt

warnings.simplefilter("ignore")  # levels past dwt_max_level are legal with periodization
rng = np.random.default_rng(20061)
cases = {"db2": [], "haar1d": [], "haar2d": []}

for n in [2, 4, 8, 16, 64, 256]:
    full = int(np.log2(n))
    for level in sorted({1, max(1, pywt.dwt_max_level(n, 4)), full}):
        x = rng.normal(size=n)
        coeffs = pywt.wavedec(x, "db2", mode="periodization", level=level)
        cases["db2"].append({"input": x.tolist(), "levels": level,
                             "coeffs": np.concatenate(coeffs).tolist()})

for n in [2, 8, 64]:
    x = rng.normal(size=n)
    coeffs = pywt.wavedec(x, "haar", mode="periodization")
    cases["haar1d"].append({"input": x.tolist(), "coeffs": np.concatenate(coeffs).tolist()})

for n in [2, 4, 16]:
    img = rng.normal(size=(n, n))
    coeffs = pywt.wavedec2(img, "haar", mode="periodization")
    out = np.zeros((n, n))
    out[0, 0] = coeffs[0][0, 0]
    for (ch, cv, cd) in coeffs[1:]:
        s = ch.shape[0]
        out[0:s, s:2 * s] = cv
        out[s:2 * s, 0:s] = ch
        out[s:2 * s, s:2 * s] = cd
    cases["haar2d"].append({"size": n, "input": img.ravel().tolist(), "coeffs": out.ravel().tolist()})

with open("pywt_vectors.json", "w") as f:
    json.dump(cases, f)
