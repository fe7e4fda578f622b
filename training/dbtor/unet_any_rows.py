"""Let an exported U-Net take images of any height.

    python -m dbtor.unet_any_rows --model ../models/unet-x4

The U-Net (dbtor/unet.py) is fully convolutional: it pads the image at the
bottom and right to a multiple of 2^depth, runs, and crops back. The exporter
(`torch.onnx.export` without dynamic axes) records the image height in two
constants: the negated height in the padding's `Mod` and the height at which
the output is cropped. This rewrites both to the height of the input (`Shape`,
`Gather`; the padding's operand as `16 - rows % 16`, non-negative, since
runtimes differ on the sign of a remainder), declares the input's and output's height symbolic (`rows`), checks
with onnxruntime that at the exported height the new graph gives the old one's
output exactly and that a taller image runs, and records `"any_rows": true`
and the file's new SHA-256 in the manifest. The weights are untouched.

Used for the image-quality rows of the anatomical test split (issue #26):
the U-Net trained on the 60 mm image (75 rows) run on the 104 mm image (130
rows), where the runtime (`Unet::load_with_rows`) accepts other heights only
from a manifest that says `any_rows`.
"""

import argparse
import hashlib
import json
import pathlib
import sys

import numpy as np
import onnx
import onnxruntime as ort
from onnx import helper, numpy_helper


def constants(graph):
    out = {}
    for n in graph.node:
        if n.op_type == "Constant":
            out[n.output[0]] = (n, numpy_helper.to_array(n.attribute[0].t))
    return out


def rewrite(model, rows):
    g = model.graph
    consts = constants(g)
    inp = g.input[0].name
    # Input height as a 0-d and a 1-d int64 tensor.
    new = [
        helper.make_node("Shape", [inp], ["rows/shape"]),
        helper.make_node("Constant", [], ["rows/axis"], value=numpy_helper.from_array(np.array(2, dtype=np.int64))),
        helper.make_node("Gather", ["rows/shape", "rows/axis"], ["rows/scalar"], axis=0),
        # 16 - rows % 16: the padding Mod then gives (-rows) mod 16 from
        # non-negative operands (runtimes differ on the sign of a remainder).
        helper.make_node("Mod", ["rows/scalar", "rows/multiple"], ["rows/rem"]),
        helper.make_node("Sub", ["rows/multiple", "rows/rem"], ["rows/neg"]),
        helper.make_node("Constant", [], ["rows/zero"], value=numpy_helper.from_array(np.array([0], dtype=np.int64))),
        helper.make_node("Unsqueeze", ["rows/scalar", "rows/zero"], ["rows/vector"]),
    ]
    replaced = {"mod": 0, "crop": 0}
    multiple = None
    for n in g.node:
        if n.op_type == "Mod" and n.input[0] in consts and n.input[1] in consts:
            v, m = consts[n.input[0]][1], consts[n.input[1]][1]
            if v.shape == () and int(v) == -rows:
                n.input[0] = "rows/neg"
                multiple = int(m)
                replaced["mod"] += 1
        if n.op_type == "Slice" and n.input[2] in consts and n.input[3] in consts:
            ends, axes = consts[n.input[2]][1], consts[n.input[3]][1]
            if ends.tolist() == [rows] and axes.tolist() == [2]:
                n.input[2] = "rows/vector"
                replaced["crop"] += 1
    if replaced != {"mod": 1, "crop": 1}:
        sys.exit(f"expected one padding Mod of -{rows} and one crop at {rows} rows, found {replaced}")
    new.insert(0, helper.make_node("Constant", [], ["rows/multiple"],
                                   value=numpy_helper.from_array(np.array(multiple or 1, dtype=np.int64))))
    for k, node in enumerate(new):
        g.node.insert(k, node)
    # The two constants are no longer read.
    used = {i for n in g.node for i in n.input}
    for n in [n for n in g.node if n.op_type == "Constant" and n.output[0] not in used]:
        g.node.remove(n)
    for v in list(g.input) + list(g.output):
        d = v.type.tensor_type.shape.dim[2]
        d.ClearField("dim_value")
        d.dim_param = "rows"
    onnx.checker.check_model(model)
    return model


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True, help="U-Net model folder (manifest.json, unet.onnx)")
    ap.add_argument("--check-rows", type=int, default=130, help="a taller height that must run")
    a = ap.parse_args(argv)
    folder = pathlib.Path(a.model)
    manifest = json.loads((folder / "manifest.json").read_text())
    if manifest.get("kind") != "unet":
        sys.exit(f"{folder}: kind {manifest.get('kind')!r}, expected 'unet'")
    if manifest.get("any_rows"):
        sys.exit(f"{folder}: already any_rows")
    path = folder / manifest["file"]
    rows = manifest["geometry"]["image"]["rows"]
    cols = manifest["geometry"]["image"]["columns"]
    old = onnx.load(str(path))
    new = rewrite(onnx.load(str(path)), rows)

    rng = np.random.default_rng(1)
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    run = lambda m, x: ort.InferenceSession(m.SerializeToString(), so, providers=["CPUExecutionProvider"]).run(
        None, {m.graph.input[0].name: x})[0]
    x = rng.random((1, 1, rows, cols), dtype=np.float32)
    a_old, a_new = run(old, x), run(new, x)
    if not np.array_equal(a_old, a_new):
        sys.exit(f"at {rows} rows the rewritten graph differs by {np.abs(a_old - a_new).max()}")
    tall = run(new, rng.random((1, 1, a.check_rows, cols), dtype=np.float32))
    if tall.shape != (1, 1, a.check_rows, cols):
        sys.exit(f"at {a.check_rows} rows the output is {tall.shape}")

    onnx.save(new, str(path))
    manifest["any_rows"] = True
    manifest["sha256"][manifest["file"]] = hashlib.sha256(path.read_bytes()).hexdigest()
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    print(f"{path}: any height; identical at {rows} rows, runs at {a.check_rows} ({tall.shape})")


if __name__ == "__main__":
    main()
