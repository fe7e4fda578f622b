#!/usr/bin/env python3
"""scikit-image's metrics on two raw little-endian float32 images.

Usage: metrics_peer.py TRUTH.f32 TEST.f32 ROWS COLS
Prints one JSON object: mse, psnr, ssim (data range = max - min of TRUTH),
computed in float64 with skimage's defaults (7x7 uniform window, sample
covariance, K1 = 0.01, K2 = 0.03).
"""
import json
import sys

import numpy as np
from skimage.metrics import mean_squared_error, peak_signal_noise_ratio, structural_similarity


def main() -> None:
    a_path, b_path, rows, cols = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    a = np.fromfile(a_path, dtype="<f4").reshape(rows, cols).astype(np.float64)
    b = np.fromfile(b_path, dtype="<f4").reshape(rows, cols).astype(np.float64)
    rng = float(a.max() - a.min())
    print(json.dumps({
        "mse": float(mean_squared_error(a, b)),
        "psnr": float(peak_signal_noise_ratio(a, b, data_range=rng)),
        "ssim": float(structural_similarity(a, b, data_range=rng)),
    }))


if __name__ == "__main__":
    main()
