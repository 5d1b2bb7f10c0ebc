#!/usr/bin/env python3
"""Reference timings for prt-linalg's sweep (benches/src/bin/linalg_sweep.rs).

Called by the sweep with the data it generated (raw little-endian files), so both sides work on
the same matrices in the same run. Prints one JSON object per line:
    {"task": ..., "rows": ..., "time_s": ..., "residual": ..., ...}
(numpy's PCA also gives "cpu_s", the mean CPU time per run).

Tasks:
  pca FILE N D RANK REPS        numpy f64 covariance + eigh, scikit-learn covariance_eigh,
                                scikit-learn full SVD (once, it is slow); residual = squared
                                Frobenius error of the rank-RANK reconstruction, in f64
  kmeans FILE N D INIT K ITERS  scikit-learn KMeans (lloyd) from the given f32 init centroids:
                                per-iteration time = (t(1 + ITERS) - t(1)) / ITERS
  nnls FILE COUNT M N REPS      scipy.optimize.nnls on COUNT problems (A m x n then b m, f64)

Run it with OPENBLAS_NUM_THREADS=1 (the sweep does) for the one-thread anchors.
"""
import json
import sys
import time

import numpy as np


def best_time(reps, fn):
    """Best of `reps` runs after a warm-up (the sweep does the same for prt-linalg)."""
    return best_and_cpu_time(reps, fn)[0]


def best_and_cpu_time(reps, fn):
    """Best wall time of `reps` runs after a warm-up, and the mean CPU time of this process per
    run (with one BLAS thread: what an idle core would take on a shared machine)."""
    fn()
    times = []
    cpu0 = time.process_time()
    for _ in range(max(1, reps)):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times), (time.process_time() - cpu0) / max(1, reps)


def residual(x, mean, components):
    """Sum of squared reconstruction errors of the centred f64 data (components: rank x d)."""
    xc = x.astype(np.float64) - np.asarray(mean, dtype=np.float64)
    v = np.asarray(components, dtype=np.float64).T
    r = xc - (xc @ v) @ v.T
    return float(np.einsum("ij,ij->", r, r))


def emit(**kw):
    print(json.dumps(kw), flush=True)


def pca(path, n, d, rank, reps):
    x = np.fromfile(path, dtype="<f4").reshape(n, d)

    def numpy_cov_eigh():
        x64 = x.astype(np.float64)
        mean = x64.mean(axis=0)
        xc = x64 - mean
        cov = (xc.T @ xc) / (n - 1)
        w, v = np.linalg.eigh(cov)
        return mean, v[:, ::-1][:, :rank].T

    t, cpu = best_and_cpu_time(reps, numpy_cov_eigh)
    mean, comps = numpy_cov_eigh()
    emit(task="pca", method="numpy f64 covariance + eigh", rows=n, time_s=t, cpu_s=cpu,
         residual=residual(x, mean, comps))

    try:
        from sklearn.decomposition import PCA
    except ImportError:
        return
    for solver, r in (("covariance_eigh", reps), ("full", 0)):
        model = PCA(n_components=rank, svd_solver=solver)
        if r == 0:
            t0 = time.perf_counter()
            model.fit(x)
            t = time.perf_counter() - t0
        else:
            t = best_time(r, lambda: PCA(n_components=rank, svd_solver=solver).fit(x))
            model.fit(x)
        emit(task="pca", method=f"scikit-learn {solver}", rows=n, time_s=t,
             residual=residual(x, model.mean_, model.components_))


def kmeans(path, n, d, init_path, k, iters):
    from sklearn.cluster import KMeans

    x = np.fromfile(path, dtype="<f4").reshape(n, d)
    init = np.fromfile(init_path, dtype="<f4").reshape(k, d)

    def run(max_iter):
        km = KMeans(n_clusters=k, init=init, n_init=1, max_iter=max_iter, tol=0.0,
                    algorithm="lloyd")
        t = time.perf_counter()
        km.fit(x)
        return time.perf_counter() - t, km

    run(1)  # warm-up
    t1 = min(run(1)[0] for _ in range(3))
    tn, km = run(1 + iters)
    emit(task="kmeans", method="scikit-learn KMeans (lloyd)", rows=n,
         time_s=(tn - t1) / iters, iterations=int(km.n_iter_), objective=float(km.inertia_))


def nnls(path, count, m, n, reps):
    from scipy.optimize import nnls as scipy_nnls

    raw = np.fromfile(path, dtype="<f8")
    size = m * n + m
    problems = [(raw[i * size:i * size + m * n].reshape(m, n), raw[i * size + m * n:(i + 1) * size])
                for i in range(count)]

    def all_problems():
        return [scipy_nnls(a, b)[0] for a, b in problems]

    t = best_time(reps, all_problems)
    xs = all_problems()
    emit(task="nnls", method="scipy.optimize.nnls", rows=m, cols=n, time_s=t / count,
         x_sum=float(sum(x.sum() for x in xs)))


def main(argv):
    task = argv[1]
    if task == "pca":
        pca(argv[2], int(argv[3]), int(argv[4]), int(argv[5]), int(argv[6]))
    elif task == "kmeans":
        kmeans(argv[2], int(argv[3]), int(argv[4]), argv[5], int(argv[6]), int(argv[7]))
    elif task == "nnls":
        nnls(argv[2], int(argv[3]), int(argv[4]), int(argv[5]), int(argv[6]))
    else:
        raise SystemExit(f"unknown task {task}")


if __name__ == "__main__":
    main(sys.argv)
