#!/usr/bin/env python3
"""onnxruntime peer of `dbtor-bench`: the same DBToR block files (fp32 or the
static int8 QDQ ones), each timed on its own at the given grid sizes with the
CPU execution provider, as a user who picked onnxruntime would run them.

Prints one JSON object: {"precision", "threads", "block_ms": [median per block
in the manifest's order], "load_s"}. Inputs are random (the timing of these
convolutions does not depend on the values).
"""
import argparse
import json
import pathlib
import time

import numpy as np
import onnxruntime as ort


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--model", required=True, type=pathlib.Path)
    p.add_argument("--precision", choices=["fp32", "int8"], required=True)
    p.add_argument("--dual", nargs=2, type=int, required=True, metavar=("VIEWS", "DET"))
    p.add_argument("--primal", nargs=2, type=int, required=True, metavar=("ROWS", "COLS"))
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    m = json.loads((a.model / "manifest.json").read_text())
    c = m["state_channels"]
    rng = np.random.default_rng(1)
    so = ort.SessionOptions()
    so.intra_op_num_threads = a.threads
    so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    block_ms = []
    load_s = 0.0
    for b in m["blocks"]:
        h, w = a.dual if b["role"] == "dual" else a.primal
        t = time.perf_counter()
        sess = ort.InferenceSession(
            str(a.model / b[a.precision]), so, providers=["CPUExecutionProvider"]
        )
        load_s += time.perf_counter() - t
        feed = {
            "state": (0.5 * rng.standard_normal((1, c, h, w))).astype(np.float32),
            "aux": (0.5 * rng.standard_normal((1, b["aux_channels"], h, w))).astype(np.float32),
        }
        sess.run(None, feed)  # warm-up
        times = []
        for _ in range(a.reps):
            t = time.perf_counter()
            sess.run(None, feed)
            times.append((time.perf_counter() - t) * 1e3)
        block_ms.append(float(np.median(times)))
    print(json.dumps({
        "precision": a.precision,
        "threads": a.threads,
        "onnxruntime": ort.__version__,
        "block_ms": block_ms,
        "load_s": load_s,
    }))


if __name__ == "__main__":
    main()
