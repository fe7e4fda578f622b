"""A firmware model folder (models/NAME, manifest format `dbtor-model/1`) read
back into PyTorch: the fp32 ONNX blocks' weights as a PrimalDual state_dict.

This is what lets a shipped model be fine-tuned when the run folder it was
exported from (its checkpoint.pt) is gone: `train.py --init models/NAME`.
Every file is checked against the manifest's SHA-256 first, as the firmware
does, and the kind and block count must match the network asked for.
"""
import hashlib
import json
import os

import numpy as np
import onnx
from onnx import numpy_helper

FORMAT = "dbtor-model/1"


class FolderError(ValueError):
    pass


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def is_model_folder(path):
    return os.path.isfile(os.path.join(path, "manifest.json"))


def read_manifest(folder):
    path = os.path.join(folder, "manifest.json")
    try:
        with open(path) as f:
            man = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise FolderError(f"{path}: {e}") from e
    if man.get("format") != FORMAT:
        raise FolderError(f"{path}: format {man.get('format')!r}, expected {FORMAT!r}")
    return man


def block_state(folder, entry):
    """The state_dict of one Block (keys net.0.weight ... net.4.bias, PReLU
    slopes net.1.weight / net.3.weight) from the block's fp32 ONNX file: its
    three Conv nodes in graph order and the two PRelu nodes between them."""
    path = os.path.join(folder, entry["fp32"])
    g = onnx.load(path).graph
    init = {i.name: numpy_helper.to_array(i) for i in g.initializer}
    convs = [n for n in g.node if n.op_type == "Conv"]
    prelus = [n for n in g.node if n.op_type == "PRelu"]
    if len(convs) != 3 or len(prelus) != 2:
        raise FolderError(f"{path}: {len(convs)} Conv and {len(prelus)} PRelu nodes, expected 3 and 2 "
                          "(an fp32 DBToR block)")
    sd = {}
    for k, n in zip((0, 2, 4), convs):
        if len(n.input) != 3 or n.input[1] not in init or n.input[2] not in init:
            raise FolderError(f"{path}: Conv {n.name!r} has no constant weight and bias")
        sd[f"net.{k}.weight"] = init[n.input[1]]
        sd[f"net.{k}.bias"] = init[n.input[2]]
    for k, n in zip((1, 3), prelus):
        if n.input[1] not in init:
            raise FolderError(f"{path}: PRelu {n.name!r} has no constant slope")
        sd[f"net.{k}.weight"] = init[n.input[1]].reshape(-1)
    return sd


def load_state_dict(folder, kind, blocks):
    """(state_dict for PrimalDual, manifest). Refuses a folder whose files do
    not match the manifest, of another kind, or with another block count."""
    import torch

    man = read_manifest(folder)
    for rel, want in man.get("sha256", {}).items():
        p = os.path.join(folder, rel)
        if not os.path.exists(p):
            raise FolderError(f"{folder}: {rel} is listed in the manifest but missing")
        if sha256(p) != want:
            raise FolderError(f"{folder}: {rel} does not match its SHA-256 in the manifest")
    if man.get("kind") != kind:
        raise FolderError(f"{folder}: a {man.get('kind')} model, not a {kind}")
    entries = man.get("blocks", [])
    have = sum(1 for e in entries if e.get("role") == "dual")
    if have != blocks or len(entries) != 2 * blocks:
        raise FolderError(f"{folder}: {have} dual and {len(entries) - have} primal blocks, "
                          f"not {blocks} of each")
    sd = {}
    for e in entries:
        for key, value in block_state(folder, e).items():
            sd[f"{e['role']}.{e['index']}.{key}"] = torch.from_numpy(np.array(value, dtype=np.float32))
    return sd, man


def load_folder(folder):
    """(state_dict, manifest, kind, blocks) of a model folder: its kind and
    block count as its manifest names them, checked by `load_state_dict`."""
    man = read_manifest(folder)
    kind = man.get("kind")
    blocks = sum(1 for e in man.get("blocks", []) if e.get("role") == "dual")
    sd, man = load_state_dict(folder, kind, blocks)
    return sd, man, kind, blocks


def stats_of(man):
    """The trainer's normalisation dict (train.tensors) from a manifest's
    `normalisation`."""
    n = man["normalisation"]
    return {"g_mean": n["g_mean"], "g_std": n["g_std"], "x_scale": n["x_scale_per_mm"]}


def check_operator(man, op, data, model):
    """Refuse (SystemExit, naming both) a dataset `data` whose operator `op`
    is not the one the model `model` (its manifest `man`) was trained with."""
    norm = man["normalisation"]["operator_norm"]
    if abs(op.norm - norm) > 1e-6 * norm:
        raise SystemExit(f"{data}: its operator (norm {op.norm}) is not the one {model} was trained with "
                         f"(norm {norm}): another geometry")


def manifest_sha256(folder):
    """SHA-256 of the folder's manifest.json: names the exact model a
    fine-tuning started from."""
    return sha256(os.path.join(folder, "manifest.json"))


def main(argv=None):
    """python -m dbtor.folder --model DIR --data DS: read the folder back into
    PyTorch, rerun its stored fixtures (max |PyTorch - fixture|, 1/mm) and
    the trainer's validation (32 slices of DS's validation split, with the
    model's own normalisation)."""
    import argparse
    import sys

    import torch

    from .data import Split
    from .model import PrimalDual
    from .operator import Operator
    from .train import tensors, validate

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("--model", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--level", default="N8")
    a = ap.parse_args(argv)
    try:
        sd, man, kind, blocks = load_folder(a.model)
    except FolderError as e:
        sys.exit(str(e))
    op = Operator(os.path.join(a.data, "operator"))
    net = PrimalDual(op, blocks=blocks, use_mask=(kind == "dbtor"))
    net.load_state_dict(sd)
    net.eval()
    stats = stats_of(man)
    val = Split(a.data, "validation", a.level)
    for fx in man.get("fixtures", []):
        f = fx["files"]
        g = np.fromfile(os.path.join(a.model, f["sinogram"]), dtype="<f4").reshape(op.sino_shape)
        want = np.fromfile(os.path.join(a.model, f["torch_fp32"]), dtype="<f4").reshape(op.image_shape)
        # the stored sinogram with its slice's mask from the dataset, as the export ran it
        _, m, x = val.batch([fx["validation_slice"]])
        gn, mt, _ = tensors((g[None], m, x), stats)
        with torch.no_grad():
            z = net(gn, mt)[0, 0].numpy() * stats["x_scale"]
        print(f"{fx['name']}: max |PyTorch - fixture| = {np.abs(z - want).max():.3e} /mm")
    mse, psnr = validate(net, val, stats)
    print(f"validation ({a.level}, 32 slices): MSE {mse:.6f} network units, PSNR {psnr:.4f} dB")


if __name__ == "__main__":
    main()
