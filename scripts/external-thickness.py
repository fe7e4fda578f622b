#!/usr/bin/env python3
"""The compressed thickness and skin of an external phantom, from its sidecar
(issue #48): the breast's vertical extent per column of the footprint, as
quantiles against the largest (what a paddle's readout would say), and the
skin's thickness at the support and at the paddle over the columns thicker
than the median. Reads the sidecar's raw volume, dims, axes, voxel size and
label map (labels mapped to "air" are not breast; "skin" is skin).

    python3 scripts/external-thickness.py phantoms/victre-pc1.toml
"""
import gzip
import os
import sys
import tomllib

import numpy as np


def main(path):
    with open(path, "rb") as f:
        sc = tomllib.load(f)
    raw = os.path.join(os.path.dirname(os.path.abspath(path)), sc["raw"])
    data = gzip.open(raw).read() if raw.endswith(".gz") else open(raw, "rb").read()
    dims = sc["dims"]  # fastest first
    a = np.frombuffer(data, dtype=np.uint8).reshape(dims[::-1])
    axes = sc["axes"][::-1]  # slowest first, as the array
    a = np.moveaxis(a, axes.index("vertical"), 0)  # vertical first
    labels = {int(k): v for k, v in sc["labels"].items()}
    air = [k for k, v in labels.items() if v == "air"]
    skin = [k for k, v in labels.items() if v == "skin"]
    vox = sc["voxel_mm"]
    breast = ~np.isin(a, air)
    th = breast.sum(0) * vox
    v = th[th > 0]
    print(f"{path}: footprint {v.size * vox * vox / 100:.1f} cm^2 of columns, largest thickness {v.max():.1f} mm")
    print("thickness quantiles (mm): " + ", ".join(f"{q} %: {np.percentile(v, q):.1f}" for q in (10, 25, 50, 75, 90, 99)))
    for d in (1, 2, 4, 8):
        print(f"columns within {d} mm of the largest: {100 * (v >= v.max() - d).mean():.1f} %")
    # Skin at the bottom and top of the columns thicker than the median.
    sk = np.isin(a, skin)
    cols = np.argwhere(th >= np.median(v))
    bottom, top = [], []
    for (i, j) in cols[:: max(1, len(cols) // 2000)]:
        col = breast[:, i, j]
        z = np.flatnonzero(col)
        lo, hi = z[0], z[-1]
        s = sk[:, i, j]
        n = 0
        while lo + n <= hi and s[lo + n]:
            n += 1
        bottom.append(n * vox)
        n = 0
        while hi - n >= lo and s[hi - n]:
            n += 1
        top.append(n * vox)
    print(f"skin at the support: median {np.median(bottom):.2f} mm; at the paddle: median {np.median(top):.2f} mm "
          f"(columns thicker than the median, {len(bottom)} sampled)")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
