"""Store an exported U-Net's weights in half precision (issue #29's lean tree).

    python -m dbtor.unet_fp16 --model ../models/unet-x4

The U-Net baseline is the largest file in the tree (31 MB of float32
weights, 7.8 M parameters). This stores every float initializer as float16
behind a `Cast` to float, so the graph still computes in float32 (tract and
onnxruntime run it as before) with weights rounded to the nearest half; it
halves the file. The fixtures' reference output is recomputed with the same
rounded weights in PyTorch (dbtor/unet.py, weights loaded from the ONNX by
name, every parameter present), so the Rust equivalence test still compares
tract with PyTorch on one network. Prints what the rounding moved: the
reference output on the fixtures before and after (network units and 1/mm),
onnxruntime on the new file against PyTorch, and the sizes. Updates the
manifest (`weights: "float16"`, the new SHA-256 of the changed files, the
command in the provenance). Refuses a model whose weights are already half.
"""

import argparse
import hashlib
import json
import pathlib
import sys

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import TensorProto, helper, numpy_helper

from .unet import UNet


def sha256(path):
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def read_f32(path):
    return np.fromfile(path, dtype="<f4")


def to_half(model):
    """Float initializers -> float16 initializers + Cast nodes (in place)."""
    g = model.graph
    casts, kept = [], []
    for init in g.initializer:
        if init.data_type != TensorProto.FLOAT:
            kept.append(init)
            continue
        a = numpy_helper.to_array(init)
        h = numpy_helper.from_array(a.astype(np.float16), init.name + "/fp16")
        kept.append(h)
        casts.append(helper.make_node("Cast", [h.name], [init.name], to=TensorProto.FLOAT,
                                      name=init.name + "/cast"))
    del g.initializer[:]
    g.initializer.extend(kept)
    nodes = casts + list(g.node)
    del g.node[:]
    g.node.extend(nodes)
    return len(casts)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True, help="an exported U-Net folder (dbtor.export_unet)")
    a = ap.parse_args(argv)
    d = pathlib.Path(a.model)
    man_path = d / "manifest.json"
    man = json.loads(man_path.read_text())
    if man.get("kind") != "unet":
        sys.exit(f"{man_path}: kind {man.get('kind')!r}, expected 'unet'")
    if man.get("weights") == "float16":
        sys.exit(f"{man_path}: the weights are already float16")
    onnx_path = d / man["file"]
    model = onnx.load(str(onnx_path))
    weights = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer
               if i.data_type == TensorProto.FLOAT}
    arch = man["architecture"]
    net = UNet(filters=arch["filters"], depth=arch["depth"]).eval()
    state = net.state_dict()
    missing = sorted(set(state) - set(weights))
    extra = sorted(set(weights) - set(state))
    if missing or extra:
        sys.exit(f"{onnx_path}: initializers and UNet parameters differ: missing {missing[:5]}, extra {extra[:5]}")
    rows, cols = man["geometry"]["image"]["rows"], man["geometry"]["image"]["columns"]
    xs = man["normalisation"]["x_scale_per_mm"]
    before_bytes = onnx_path.stat().st_size

    def reference(rounded):
        sd = {k: torch.from_numpy((v.astype(np.float16) if rounded else v).astype(np.float32))
              for k, v in weights.items()}
        net.load_state_dict(sd, strict=True)
        out = {}
        with torch.no_grad():
            for fx in man["fixtures"]:
                # fixtures store the FBP in 1/mm and the output in 1/mm
                fbp = read_f32(d / fx["files"]["fbp"]).reshape(1, 1, rows, cols)
                y = net(torch.from_numpy(fbp / xs).float()).numpy().reshape(-1) * xs
                out[fx["name"]] = y.astype(np.float32)
        return out

    full, half = reference(False), reference(True)
    for fx in man["fixtures"]:
        stored = read_f32(d / fx["files"]["torch_fp32"])
        n = fx["name"]
        same = np.max(np.abs(full[n] - stored))
        moved = np.max(np.abs(half[n] - full[n]))
        rms = float(np.sqrt(np.mean((half[n] - full[n]) ** 2)))
        print(f"{n}: PyTorch (float32 weights from the ONNX) vs the stored reference: max {same:.2e} /mm; "
              f"half weights move the output by max {moved:.2e} /mm ({moved / xs:.2e} network units), RMS {rms:.2e} /mm")
        if same > 1e-5:
            sys.exit(f"{n}: the network rebuilt from {onnx_path} does not reproduce the stored reference ({same:.2e} /mm)")

    n_cast = to_half(model)
    onnx.checker.check_model(model)
    onnx.save(model, str(onnx_path))
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    for fx in man["fixtures"]:
        n = fx["name"]
        fbp = read_f32(d / fx["files"]["fbp"]).reshape(1, 1, rows, cols)
        y = sess.run(None, {"fbp": (fbp / xs).astype(np.float32)})[0].reshape(-1) * xs
        diff = float(np.max(np.abs(y - half[n])))
        print(f"{n}: onnxruntime on the half-weight file vs PyTorch with the same weights: max {diff:.2e} /mm")
        if diff > 1e-5:
            sys.exit(f"{n}: onnxruntime and PyTorch disagree on the half-weight network ({diff:.2e} /mm)")
        half[n].astype("<f4").tofile(d / fx["files"]["torch_fp32"])
        fx["onnxruntime_vs_torch_max_abs_per_mm"] = diff
    after_bytes = onnx_path.stat().st_size
    print(f"{onnx_path}: {n_cast} initializers to float16, {before_bytes} -> {after_bytes} bytes")

    man["weights"] = "float16"
    for k in man["sha256"]:
        man["sha256"][k] = sha256(d / k)
    man.setdefault("provenance", {})["weights_to_float16"] = (
        "python -m dbtor.unet_fp16 --model " + str(a.model)
        + f" (float32 weights rounded to float16, a Cast each; {before_bytes} -> {after_bytes} bytes;"
        " fixtures' torch_fp32 recomputed with the rounded weights)")
    man_path.write_text(json.dumps(man, indent=2) + "\n")
    print(f"wrote {man_path}")


if __name__ == "__main__":
    main()
