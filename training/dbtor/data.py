"""The `host-sim dataset` format (DATASET.md), read with numpy.memmap."""
import json
import os

import numpy as np


class Split:
    """One split; `sinos` holds the network input: the sinograms `sino-<level>`,
    or with `input="fbp"` their FBP `fbp-<level>` (`host-sim fbp`, U-Net)."""

    def __init__(self, root, name, level, input="sino"):
        with open(os.path.join(root, "manifest.json")) as f:
            self.manifest = json.load(f)
        if self.manifest.get("format") != "dbtor-dataset/1":
            raise ValueError(f"{root}/manifest.json: not a dbtor-dataset/1 manifest")
        split = next((s for s in self.manifest["splits"] if s["name"] == name), None)
        if split is None:
            raise ValueError(f"{root}: no split named {name!r}")
        self.split = split
        arrays = {a["name"]: a for a in split["arrays"]}
        key = f"{input}-{level}"
        if key not in arrays:
            have = [k for k in arrays if k.startswith(input + "-")]
            hint = " (make it with `host-sim fbp --data DIR --level LEVEL`)" if input == "fbp" else ""
            raise ValueError(f"{root}/{name}: no array {key!r} (have {have}){hint}")

        if arrays["images"]["shape"][0] == 0:
            raise ValueError(f"{root}/{name}: the split is empty (export more slices: validation "
                             "takes every tenth phantom)")

        def mm(a):
            return np.memmap(os.path.join(root, name, a["file"]), dtype=a["dtype"], mode="r",
                             shape=tuple(a["shape"]))

        self.images = mm(arrays["images"])
        self.masks = mm(arrays["masks"])
        self.sinos = mm(arrays[key])
        self.n = self.images.shape[0]

    def batch(self, idx):
        idx = np.sort(np.asarray(idx))
        return (np.ascontiguousarray(self.sinos[idx]), np.ascontiguousarray(self.masks[idx]),
                np.ascontiguousarray(self.images[idx]))


def statistics(split, max_slices=2000, seed=0):
    """Normalisation constants from the training split: sinogram mean and sd,
    image RMS (1/mm). A fixed random subset keeps this fast on large sets."""
    rng = np.random.default_rng(seed)
    idx = rng.choice(split.n, size=min(max_slices, split.n), replace=False)
    g, _, x = split.batch(idx)
    return {
        "g_mean": float(g.mean(dtype=np.float64)),
        "g_std": float(g.std(dtype=np.float64)),
        "x_scale": float(np.sqrt((x.astype(np.float64) ** 2).mean())),
        "slices": int(len(idx)),
    }
