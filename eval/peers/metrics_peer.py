#!/usr/bin/env python3
"""scikit-image's metrics on two raw little-endian float32 images.

Usage: metrics_peer.py TRUTH.f32 TEST.f32 ROWS COLS
Prints one JSON object: mse, psnr, ssim (data range = max - min of TRUTH),
computed in float64 with skimage's defaults (7x7 uniform window, sample
covariance, K1 = 0.01, K2 = 0.03), and ssim_regions: skimage's full SSIM map,
cropped as its mean is, averaged over the windows wholly inside the truth's
tissue (TRUTH > 0), across its outline, and wholly in air (mean and share of
the windows; mean null where there are none).
"""
import json
import sys

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from skimage.metrics import mean_squared_error, peak_signal_noise_ratio, structural_similarity

WIN = 7


def regions(smap, tissue):
    pad = WIN // 2
    inner = smap[pad:-pad, pad:-pad]
    count = sliding_window_view(tissue.astype(np.int64), (WIN, WIN)).sum(axis=(2, 3))
    out = {}
    for name, sel in (("inside", count == WIN * WIN), ("outline", (count > 0) & (count < WIN * WIN)),
                      ("air", count == 0)):
        out[name] = {"mean": float(inner[sel].mean()) if sel.any() else None,
                     "share": float(sel.mean())}
    return out


def main() -> None:
    a_path, b_path, rows, cols = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    a = np.fromfile(a_path, dtype="<f4").reshape(rows, cols).astype(np.float64)
    b = np.fromfile(b_path, dtype="<f4").reshape(rows, cols).astype(np.float64)
    rng = float(a.max() - a.min())
    ssim, smap = structural_similarity(a, b, data_range=rng, full=True)
    print(json.dumps({
        "mse": float(mean_squared_error(a, b)),
        "psnr": float(peak_signal_noise_ratio(a, b, data_range=rng)),
        "ssim": float(ssim),
        "ssim_regions": regions(smap, a > 0),
    }))


if __name__ == "__main__":
    main()
