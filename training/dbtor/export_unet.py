"""Export a trained U-Net run (the FBP post-processing baseline) for the Rust
runtime and the evaluation.

    python -m dbtor.export_unet --run RUN --data DS --out models/NAME [--fixtures 2]

Writes `unet.onnx` (opset 17, input `fbp` [1, 1, rows, cols] in units of
x_scale, output `out`, the image in the same unit; padding to a multiple of 16
and the crop back happen inside), fixtures for the Rust equivalence test (the
FBP input of validation slices, their truth and the PyTorch output) and
`manifest.json` (format `dbtor-unet/1`: geometry, normalisation, SHA-256 of
every file, provenance and the trainer's last validation).
"""
import argparse
import json
import os
import sys

import numpy as np
import onnx
import onnxruntime as ort
import torch

from .data import Split
from .export import provenance, sha256, trainer_validation
from .unet import DEPTH, FILTERS, UNet

OPSET = 17


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--name", default=None)
    ap.add_argument("--fixtures", type=int, default=2, help="validation slices stored as fixtures")
    a = ap.parse_args(argv)
    ck = torch.load(os.path.join(a.run, "checkpoint.pt"), weights_only=False)
    if ck["model_kind"] != "unet":
        sys.exit(f"{a.run}: a {ck['model_kind']!r} run; this exporter takes U-Net runs (dbtor.export takes the others)")
    with open(os.path.join(a.run, "run.json")) as f:
        run = json.load(f)
    net = UNet()
    net.load_state_dict(ck["model"])
    net.eval()
    stats = ck["stats"]
    xs = stats["x_scale"]
    level = ck["options"]["level"]
    os.makedirs(os.path.join(a.out, "fixtures"), exist_ok=True)
    rows, cols = run["geometry"]["image"]["rows"], run["geometry"]["image"]["columns"]

    path = os.path.join(a.out, "unet.onnx")
    example = torch.zeros(1, 1, rows, cols)
    torch.onnx.export(net, (example,), path, input_names=["fbp"], output_names=["out"],
                      opset_version=OPSET, dynamo=False)
    onnx.checker.check_model(onnx.load(path))
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])

    val = Split(a.data, "validation", level, input="fbp")
    fx_idx = np.linspace(0, val.n - 1, a.fixtures + 2).astype(int)[1:-1]
    fixtures = []
    for k, j in enumerate(fx_idx):
        fbp, _, truth = val.batch([j])
        x = torch.from_numpy(fbp / xs).float().unsqueeze(1)
        with torch.no_grad():
            ref = (net(x) * xs).numpy()[0, 0]
        ort_out = sess.run(None, {"fbp": x.numpy()})[0][0, 0] * xs
        stem = f"case{k}"
        files = {}
        for name, arr in (("fbp", fbp[0]), ("truth", truth[0]), ("torch_fp32", ref)):
            p = os.path.join(a.out, "fixtures", f"{stem}-{name}.f32")
            np.asarray(arr, dtype="<f4").tofile(p)
            files[name] = os.path.relpath(p, a.out)
        diff = float(np.abs(ort_out - ref).max())
        fixtures.append({"name": stem, "validation_slice": int(j), "files": files,
                         "onnxruntime_vs_torch_max_abs_per_mm": diff})
        print(f"fixture {stem}: onnxruntime vs PyTorch max abs {diff:.2e} /mm", flush=True)

    everything = sorted(os.path.relpath(os.path.join(r, n), a.out)
                        for r, _, names in os.walk(a.out) for n in names if n != "manifest.json")
    manifest = {
        "format": "dbtor-unet/1",
        "name": a.name or os.path.basename(os.path.normpath(a.out)),
        "kind": "unet",
        "geometry": run["geometry"],
        "file": "unet.onnx",
        "architecture": {"depth": DEPTH, "filters": FILTERS, "normalisation": "instance (affine)",
                         "activation": "ReLU", "upsampling": "2x2 transposed convolution",
                         "output": "input + 1x1 convolution (residual)"},
        "input": f"FBP of the log sinogram (dbt_recon::Fbp: Hann-windowed ramp, zero outside the thickness "
                 f"mask), 1/mm, divided by x_scale_per_mm; trained at {level}",
        "normalisation": {"x_scale_per_mm": xs,
                          "rule": "out (1/mm) = net(fbp / x_scale_per_mm) * x_scale_per_mm"},
        "opset": OPSET,
        "fixtures": fixtures,
        "sha256": {p: sha256(os.path.join(a.out, p)) for p in everything},
        "provenance": provenance(run, ck, "dbtor.export_unet", argv),
    }
    validation = trainer_validation(a.run, level, "--unet")
    if validation:
        manifest["validation"] = validation
    with open(os.path.join(a.out, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=2)
    print(f"wrote {a.out}/manifest.json ({len(everything)} files)")


if __name__ == "__main__":
    main()
