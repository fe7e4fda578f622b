#!/usr/bin/env python3
"""Peers of the projector benchmark, measured in the same run as our projector.

* ASTRA Toolbox (PyPI astra-toolbox 2.5.0), CPU `line_fanflat` projector with a
  `fanflat_vec` geometry built from the same geometry definition.
* scipy CSR matrix-vector products with our exported operator.

Reads a JSON job from argv[1]; prints one JSON object on stdout.
"""
import json
import sys
import time

import numpy as np


def median_ms(fn, warmup, reps):
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ts))


def astra_geometry(g):
    import astra

    nv, nd = g["views"]["count"], g["detector"]["elements"]
    angles = np.deg2rad(np.linspace(g["views"]["first_deg"], g["views"]["last_deg"], nv))
    r, d, p = g["source_to_center_mm"], g["source_to_detector_mm"], g["detector"]["pitch_mm"]
    vec = np.zeros((nv, 6))
    for i, t in enumerate(angles):
        s, c = np.sin(t), np.cos(t)
        vec[i] = [r * s, r * c, (r - d) * s, (r - d) * c, p * c, -p * s]
    proj_geom = astra.create_proj_geom("fanflat_vec", nd, vec)
    cols, rows, px = g["image"]["columns"], g["image"]["rows"], g["image"]["pixel_mm"]
    w, h = cols * px, rows * px
    vol_geom = astra.create_vol_geom(rows, cols, -w / 2, w / 2, -h / 2, h / 2)
    return proj_geom, vol_geom


def main():
    job = json.load(open(sys.argv[1]))
    g = job["geometry"]
    rows, cols = g["image"]["rows"], g["image"]["columns"]
    nv, nd = g["views"]["count"], g["detector"]["elements"]
    img = np.fromfile(job["image"], dtype="<f4").reshape(rows, cols)
    ours_fwd = np.fromfile(job["ours_forward"], dtype="<f4").reshape(nv, nd)
    sino_in = np.fromfile(job["sinogram"], dtype="<f4").reshape(nv, nd)
    ours_adj = np.fromfile(job["ours_adjoint"], dtype="<f4").reshape(rows, cols)
    reps, warmup = job["reps"], job["warmup"]
    out = {}
    try:
        import astra

        proj_geom, vol_geom = astra_geometry(g)
        pid = astra.create_projector("line_fanflat", proj_geom, vol_geom)

        def timed(kind, vol_key, vol, sino):
            """Median time of ASTRA's FP or BP algorithm and its output."""
            vid = astra.data2d.create("-vol", vol_geom, vol)
            sid = astra.data2d.create("-sino", proj_geom, sino)
            cfg = astra.astra_dict(kind)
            cfg["ProjectorId"], cfg["ProjectionDataId"], cfg[vol_key] = pid, sid, vid
            alg = astra.algorithm.create(cfg)
            ms = median_ms(lambda: astra.algorithm.run(alg), warmup, reps)
            return ms, astra.data2d.get(sid if kind == "FP" else vid)

        out["astra_forward_ms"], a_fwd = timed("FP", "VolumeDataId", img, 0)
        out["astra_adjoint_ms"], a_adj = timed("BP", "ReconstructionDataId", 0, sino_in)
        out["astra_vs_ours_forward_rel_l2"] = float(np.linalg.norm(a_fwd - ours_fwd) / np.linalg.norm(a_fwd))
        per_view = np.linalg.norm(a_fwd - ours_fwd, axis=1) / np.linalg.norm(a_fwd, axis=1)
        out["astra_vs_ours_forward_worst_view_rel_l2"] = float(per_view.max())
        out["astra_vs_ours_adjoint_rel_l2"] = float(np.linalg.norm(a_adj - ours_adj) / np.linalg.norm(a_adj))
        out["astra_version"] = astra.__version__
    except Exception as e:  # the benchmark still reports our numbers
        out["astra_error"] = repr(e)
    try:
        import scipy
        import scipy.sparse as sp

        raw = open(job["csr"], "rb").read()
        assert raw[:8] == b"DBTCSR01", "bad CSR magic"
        n_rows, n_cols, nnz = np.frombuffer(raw[8:32], dtype="<u8")
        off = 64
        indptr = np.frombuffer(raw, dtype="<u8", count=n_rows + 1, offset=off)
        off += 8 * (n_rows + 1)
        indices = np.frombuffer(raw, dtype="<u4", count=nnz, offset=off)
        off += 4 * nnz
        values = np.frombuffer(raw, dtype="<f4", count=nnz, offset=off)
        a = sp.csr_matrix((values, indices.astype(np.int32), indptr.astype(np.int64)), shape=(n_rows, n_cols))
        x = img.ravel()
        y = sino_in.ravel()
        at = a.T.tocsr()
        out["csr_forward_ms"] = median_ms(lambda: a @ x, warmup, reps)
        out["csr_adjoint_ms"] = median_ms(lambda: at @ y, warmup, reps)
        out["csr_vs_ours_forward_rel_l2"] = float(np.linalg.norm(a @ x - ours_fwd.ravel()) / np.linalg.norm(a @ x))
        out["csr_nnz"] = int(nnz)
        out["scipy_version"] = scipy.__version__
    except Exception as e:
        out["csr_error"] = repr(e)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
