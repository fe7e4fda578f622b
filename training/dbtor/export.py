"""Export a trained run to a firmware model folder.

    python -m dbtor.export --run RUN --data DS --out models/NAME [--name NAME]
        [--calibration 16] [--fixtures 2] [--int8-run QATRUN] [--gptq 64]
    python -m dbtor.export --from-model models/NAME --data DS --out DIR --gptq 64

--from-model re-quantises a model folder whose run is gone: its fp32 blocks
are read back (folder.py) and copied byte for byte, its run.json and
curve.csv kept, and only the int8 blocks, the fixtures and the manifest are
made anew (its provenance names the folder it came from).

Writes, per block in execution order (dual 0, primal 0, dual 1, ...), an fp32
ONNX file (opset 17, inputs `state` [n,5,h,w] and `aux` [n,k,h,w], output
`out` = state + block(cat(state, aux)), the residual update inside) and a static
int8 QDQ version (onnxruntime quantize_static: per-channel int8 weights, int8
activations, calibrated on the inputs each block sees on training slices).
With --int8-run, the int8 blocks are quantised from the weights of another
run of the same model, normally a quantisation-aware fine-tuning of RUN
(`train.py --init RUN --qat`, qat.py); the fp32 blocks stay RUN's. A --qat
run is exported in the form it simulated (--equalise 0, --int8-form as its
--qat-form); anything else is refused.

Two choices make the int8 blocks lose less than onnxruntime's plain output
(measured in models/README.md):
- --equalise ALPHA (default 0.5; 0 = off): cross-layer equalisation of the
  hidden channels before quantising (equalize.py), which leaves the float
  function unchanged.
- --int8-form, which activations are quantised (qat.py writes the graphs
  out):
  - conv-inputs (default): only what the convolutions read, int8 x int8
    into int32 as in every form; their outputs are dequantised and stay
    float through the PReLU (quantised after it, as the next convolution's
    input) and into the residual sum. The concatenation is multiplied by
    one factor per channel before it is quantised (equalize.prescale; a Mul
    node in the graph) and conv1's input channels are divided by it. Three
    quantisations per block instead of eight.
  - float-residual: every activation but the residual sum, which reads the
    state unquantised, `out = state + DQ(Q(conv3))`.
  - plain: onnxruntime's graph as quantize_static makes it.
  The state that flows from block to block stays float in all three, as it
  does in the runtime between blocks anyway.
- --gptq N (default 0 = off): the int8 weights rounded by GPTQ on N
  training slices instead of to the nearest level (gptq.py; conv-inputs
  form only).
Also fixtures for the Rust equivalence test (a sinogram, its thickness, the
PyTorch fp32 reconstruction and the onnxruntime int8 one) and manifest.json
with the geometry, normalisation, block order, SHA-256 of every file,
provenance and validation metrics.
"""
import argparse
import copy
import logging
import json
import os
import shutil
import sys

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod, QuantFormat,
                                      QuantType, quantize_static)

from .data import Split
from .model import STATE, PrimalDual
from .equalize import equalise, prescale
from .folder import load_folder, manifest_sha256, sha256, stats_of
from . import gptq
from .qat import FORMS, calibration_batches, form_of
from .operator import Operator
from .train import tensors

OPSET = 17


def provenance(run, ck, tool, argv):
    """The manifest's `provenance`: the training command and options, iterations,
    minutes, dataset provenance, and this export's command."""
    return {
        "train_command": run["command"], "options": run["options"],
        "iterations": ck["iteration"], "training_minutes": round(ck["elapsed_s"] / 60, 1),
        "dataset_provenance": run["dataset_provenance"], "torch": torch.__version__,
        "init": run.get("init"),
        "export_command": " ".join([f"python -m {tool}"] + (argv or sys.argv[1:])),
    }


def folder_checkpoint(folder):
    """(checkpoint-like dict, run.json, manifest) of a model folder, for
    --from-model: the fp32 weights read back from its ONNX blocks."""
    sd, man, kind, n = load_folder(folder)
    with open(os.path.join(folder, "run.json")) as f:
        run = json.load(f)
    prov = man["provenance"]
    ck = {"model": sd, "model_kind": kind, "blocks": n, "options": run["options"], "stats": stats_of(man),
          "iteration": prov["iterations"], "elapsed_s": prov["training_minutes"] * 60}
    return ck, run, man


def trainer_validation(run_dir, level, flag):
    """The trainer's last validation (validation split, never trained on) from
    RUN/curve.csv, or None; `flag` names the evaluation option for the test set."""
    curve = os.path.join(run_dir, "curve.csv")
    if not os.path.exists(curve):
        return None
    import csv
    rows = [r for r in csv.DictReader(open(curve)) if r["val_mse"]]
    if not rows:
        return None
    r = rows[-1]
    return {
        "split": "validation", "slices": 32, "noise": level, "iteration": int(r["iteration"]),
        "mse_network_units": float(r["val_mse"]), "psnr_db_per_slice_range": float(r["val_psnr_db"]),
        "note": f"from the trainer's curve; the test-set table is dbt-eval baselines {flag}",
    }


def drop_quantisations(path, keep):
    """Take activation quantisations out of onnxruntime's QDQ block: every
    edge that reads DQ(Q(x)) of an activation x, a node's input or the
    graph's output, reads x instead unless `keep(node, k, x)` (node None for
    the graph output, k the input's index); a graph output that becomes
    unquantised keeps its name. Weights and biases keep their
    DequantizeLinear."""
    mo = onnx.load(path)
    g = mo.graph
    inits = {i.name for i in g.initializer}
    producer = {o: n for n in g.node for o in n.output}
    source = {}  # DQ output -> the activation it quantises
    for dq in g.node:
        if dq.op_type != "DequantizeLinear" or dq.input[0] in inits:
            continue
        q = producer.get(dq.input[0])
        if q is None or q.op_type != "QuantizeLinear":
            raise SystemExit(f"{path}: DequantizeLinear {dq.name!r} does not read a QuantizeLinear")
        source[dq.output[0]] = q.input[0]
    for n in g.node:
        for k, i in enumerate(n.input):
            if i in source and not keep(n, k, source[i]):
                n.input[k] = source[i]
    for out in g.output:
        x = source.get(out.name)
        if x is not None and not keep(None, 0, x):
            # the tensor x takes the output's name; the output's DQ goes below
            g.node.remove(producer[out.name])
            for n in g.node:
                n.output[:] = [out.name if o == x else o for o in n.output]
                n.input[:] = [out.name if i == x else i for i in n.input]
    # Q and DQ nodes nobody reads any more, DQ first.
    outs = {o.name for o in g.output}
    for op in ("DequantizeLinear", "QuantizeLinear"):
        used = {i for n in g.node for i in n.input} | outs
        for n in [n for n in g.node if n.op_type == op and n.output[0] not in used]:
            g.node.remove(n)
    used = {i for n in g.node for i in n.input}
    for init in list(g.initializer):
        if init.name not in used:
            g.initializer.remove(init)
    onnx.checker.check_model(mo)
    onnx.save(mo, path)
    return mo


def float_residual(path):
    """The float-residual form: the residual sum reads the raw state and its
    result is the output unquantised,
    Add(DQ(Q(state)), c) -> Q -> DQ -> out   becomes   Add(state, c) -> out."""
    mo = drop_quantisations(path, lambda n, k, x: n is not None and not (n.op_type == "Add" and x == "state"))
    add = [n for n in mo.graph.node if "out" in n.output]
    if len(add) != 1 or add[0].op_type != "Add" or "state" not in add[0].input:
        raise SystemExit(f"{path}: the block output is not Add(state, ...) after taking out its quantisation")


def conv_inputs_only(path):
    """The conv-inputs form: only the activation quantisations that a Conv
    reads as its input stay, so the convolutions' outputs, the PReLU inputs,
    the state, aux and raw concatenation and the residual sum are float."""
    drop_quantisations(path, lambda n, k, x: n is not None and n.op_type == "Conv" and k == 0)


class Prescaled(torch.nn.Module):
    """A block with its concatenation multiplied by `k` per channel and its
    first convolution's input channels divided by `k`: the same float
    function (to rounding), the source of the conv-inputs int8 graph."""

    def __init__(self, blk, k):
        super().__init__()
        self.net = copy.deepcopy(blk.net)
        with torch.no_grad():
            self.net[0].weight.div_(k.view(1, -1, 1, 1))
        self.register_buffer("prescale", k.view(1, -1, 1, 1).clone())

    def forward(self, state, aux):
        return state + self.net(torch.cat([state, aux], 1) * self.prescale)


def blocks_in_order(net):
    for i in range(net.n_blocks):
        yield "dual", i, net.dual[i]
        yield "primal", i, net.primal[i]


def capture_block_inputs(net, g, m):
    """Run the network and record (state, aux) at every block."""
    seen = {}
    hooks = []
    for role, i, blk in blocks_in_order(net):
        def hook(mod, args, role=role, i=i):
            seen.setdefault((role, i), []).append((args[0].detach().numpy().copy(),
                                                   args[1].detach().numpy().copy()))
        hooks.append(blk.register_forward_pre_hook(hook))
    with torch.no_grad():
        out = net(g, m)
    for h in hooks:
        h.remove()
    return out, seen


class Reader(CalibrationDataReader):
    def __init__(self, samples):
        self.it = iter([{"state": s, "aux": a} for s, a in samples])

    def get_next(self):
        return next(self.it, None)


def run_onnx_chain(files, op, g, m, n_blocks, use_mask=True):
    """The unrolled loop with onnxruntime blocks (reference for the int8 fixture)."""
    sessions = [ort.InferenceSession(f, providers=["CPUExecutionProvider"]) for f in files]
    return run_onnx_sessions(sessions, op, g, m, n_blocks, use_mask)


def run_onnx_sessions(sessions, op, g, m, n_blocks, use_mask=True):
    """The unrolled loop of model.py with onnxruntime sessions, one per block in
    execution order (dual 0, primal 0, dual 1, ...); g and m normalised as by
    train.tensors. Returns f[0] in units of x_scale."""
    b = g.shape[0]
    h = torch.zeros(b, STATE, *op.sino_shape)
    f = torch.zeros(b, STATE, *op.image_shape)
    with torch.no_grad():
        pm = op.forward(m) if use_mask else None
        for i in range(n_blocks):
            pf = op.forward(f[:, 1:2])
            aux = torch.cat([pf, g, pm], 1) if use_mask else torch.cat([pf, g], 1)
            h = torch.from_numpy(sessions[2 * i].run(None, {"state": h.numpy(), "aux": aux.numpy()})[0])
            bh = op.adjoint(h[:, 0:1])
            aux = torch.cat([bh, m], 1) if use_mask else bh
            f = torch.from_numpy(sessions[2 * i + 1].run(None, {"state": f.numpy(), "aux": aux.numpy()})[0])
    return f[:, 0:1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--run", help="a training run folder (checkpoint.pt, run.json)")
    src.add_argument("--from-model", help="a model folder: keep its fp32 blocks, quantise anew")
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--name", default=None)
    ap.add_argument("--calibration", type=int, default=16, help="training slices for int8 calibration")
    ap.add_argument("--fixtures", type=int, default=2, help="validation slices stored as fixtures")
    ap.add_argument("--validation", default=None, help="JSON of validation metrics to embed")
    ap.add_argument("--int8-run", default=None,
                    help="quantise the int8 blocks from this run's weights (a --qat fine-tuning of --run)")
    ap.add_argument("--equalise", type=float, default=0.5,
                    help="cross-layer equalisation exponent for the int8 blocks (equalize.py); 0 = off")
    ap.add_argument("--int8-form", choices=list(FORMS), default="conv-inputs",
                    help="conv-inputs: only the convolutions' inputs quantised (the concatenation "
                         "prescaled per channel); float-residual: every activation but the residual sum; "
                         "plain: onnxruntime's graph as it makes it")
    ap.add_argument("--gptq", type=int, default=0,
                    help="round the int8 weights by GPTQ on this many training slices (0: to the nearest)")
    ap.add_argument("--gptq-asymmetric", action="store_true",
                    help="with --gptq: each convolution's target is the float network's output on its own "
                         "inputs, the bias refitted with the weights (gptq.py)")
    a = ap.parse_args(argv)
    logging.getLogger().setLevel(logging.ERROR)  # onnxruntime's pre-processing advice
    if a.gptq < 0 or (a.gptq and a.int8_form != "conv-inputs"):
        sys.exit(f"--gptq {a.gptq}: a number of slices, for the conv-inputs form only")
    if a.gptq_asymmetric and not a.gptq:
        sys.exit("--gptq-asymmetric needs --gptq N")
    if a.from_model:
        ck, run, source = folder_checkpoint(a.from_model)
        a.run = a.from_model  # its run.json and curve.csv are copied like a run's
    else:
        source = None
        ck = torch.load(os.path.join(a.run, "checkpoint.pt"), weights_only=False)
        with open(os.path.join(a.run, "run.json")) as f:
            run = json.load(f)
    op = Operator(os.path.join(a.data, "operator"))
    kind = ck["model_kind"]
    if kind not in ("dbtor", "lpd"):
        sys.exit(f"cannot export a {kind!r} run with this exporter")
    use_mask = kind == "dbtor"

    def network(checkpoint):
        n = PrimalDual(op, blocks=checkpoint["blocks"], use_mask=use_mask)
        n.load_state_dict(checkpoint["model"])
        return n.eval()

    net = network(ck)
    stats = ck["stats"]
    level = ck["options"]["level"]
    os.makedirs(a.out, exist_ok=True)
    for sub in ("fp32", "int8", "fixtures"):
        os.makedirs(os.path.join(a.out, sub), exist_ok=True)

    # The network the int8 blocks come from: RUN's, or --int8-run's.
    qnet, run8, ck8 = net, None, None
    if a.int8_run:
        ck8 = torch.load(os.path.join(a.int8_run, "checkpoint.pt"), weights_only=False)
        with open(os.path.join(a.int8_run, "run.json")) as f:
            run8 = json.load(f)
        if (ck8["model_kind"], ck8["blocks"]) != (kind, ck["blocks"]):
            sys.exit(f"--int8-run {a.int8_run}: a {ck8['model_kind']} of {ck8['blocks']} blocks, "
                     f"not a {kind} of {ck['blocks']}")
        if ck8["stats"] != stats or run8["geometry"] != run["geometry"]:
            sys.exit(f"--int8-run {a.int8_run}: trained with another normalisation or geometry than {a.run}")
        if run8["options"].get("qat"):
            # A QAT run learnt the rounding of one graph: export that one.
            if a.equalise > 0:
                sys.exit(f"--int8-run {a.int8_run}: a --qat run simulates the blocks unequalised; "
                         "pass --equalise 0")
            # (runs made before --qat-form named only their residual, as
            # manifests did)
            simulated = run8.get("qat_form") or form_of({"residual": run8.get("qat_residual")})
            if simulated != a.int8_form:
                sys.exit(f"--int8-run {a.int8_run}: the run simulated the {simulated} graph, "
                         f"not --int8-form {a.int8_form}")
        qnet = network(ck8)

    # Calibration inputs: training slices (never validation or test), the
    # slices train.py --qat measures its ranges on.
    train = Split(a.data, "train", level)
    cal_batches = calibration_batches(train, stats, a.calibration)
    n_cal = sum(g.shape[0] for g, _ in cal_batches)
    if a.equalise > 0:
        if qnet is net:
            qnet = network(ck)  # a copy: the fp32 blocks stay the trained weights
        with torch.no_grad():
            before = qnet(*cal_batches[0])
        equalise(qnet, lambda: [qnet(g, m) for g, m in cal_batches], a.equalise)
        with torch.no_grad():
            after = qnet(*cal_batches[0])
        # Equalisation must not change the float function: float32 rounding
        # through 20 blocks stays below 1e-4 of the output's range.
        drift = float((after - before).abs().max() / (before.max() - before.min()))
        if drift > 1e-4:
            sys.exit(f"equalisation changed the float network by {drift:.2e} of its range")
        print(f"equalised the hidden channels (alpha {a.equalise}): float output moved by {drift:.1e} "
              "of its range", flush=True)
    samples = {}
    for g, m in cal_batches:
        _, seen = capture_block_inputs(qnet, g, m)
        for k, v in seen.items():
            for state, aux in v:
                for j in range(state.shape[0]):
                    samples.setdefault(k, []).append((state[j:j + 1], aux[j:j + 1]))

    chain = None
    if a.gptq:
        rng = np.random.default_rng(gptq.GPTQ_SEED)
        idx = rng.choice(train.n, size=min(a.gptq, train.n), replace=False)
        chain = gptq.Chain(op, [tensors(train.batch(idx[s:s + 8]), stats)[:2] for s in range(0, len(idx), 8)],
                           use_mask, a.gptq_asymmetric)
    blocks = []
    fp32_files, int8_files = [], []
    qblocks = {(role, i): blk for role, i, blk in blocks_in_order(qnet)}
    for role, i, blk in blocks_in_order(net):
        stem = f"{role}{i:02d}"
        f32 = os.path.join(a.out, "fp32", stem + ".onnx")
        i8 = os.path.join(a.out, "int8", stem + ".onnx")
        state_ex, aux_ex = samples[(role, i)][0]

        def to_onnx(module, path):
            torch.onnx.export(module, (torch.from_numpy(state_ex), torch.from_numpy(aux_ex)), path,
                              input_names=["state", "aux"], output_names=["out"], opset_version=OPSET,
                              dynamic_axes={"state": {0: "n", 2: "h", 3: "w"}, "aux": {0: "n", 2: "h", 3: "w"},
                                            "out": {0: "n", 2: "h", 3: "w"}},
                              dynamo=False)
            onnx.checker.check_model(onnx.load(path))

        if source is None:
            to_onnx(blk, f32)
        else:
            entry = source["blocks"][len(blocks)]
            if (entry["role"], entry["index"]) != (role, i):
                sys.exit(f"--from-model {a.from_model}: block {len(blocks)} is {entry['role']} {entry['index']}, "
                         f"not {role} {i}")
            shutil.copyfile(os.path.join(a.from_model, entry["fp32"]), f32)
        q_src, q_blk, exclude = f32, qblocks[(role, i)], []
        if a.int8_form == "conv-inputs":
            # k from the concatenation's per-channel range on the calibration inputs
            cat = np.concatenate([np.concatenate([s, x], 1) for s, x in samples[(role, i)]], 0)
            k = prescale(torch.from_numpy(cat.min(axis=(0, 2, 3))), torch.from_numpy(cat.max(axis=(0, 2, 3))))
            q_blk = Prescaled(q_blk, k)
            exclude = ["/Mul"]  # the prescale stays a float multiplication
        if q_blk is not blk:
            q_src = os.path.join(a.out, "int8", stem + ".fp32-source.onnx")
            to_onnx(q_blk, q_src)
            if exclude and not any(n.name in exclude for n in onnx.load(q_src).graph.node):
                raise SystemExit(f"{q_src}: the prescale's Mul node is not named {exclude[0]!r}")
        quantize_static(q_src, i8, Reader(samples[(role, i)]), quant_format=QuantFormat.QDQ,
                        per_channel=True, activation_type=QuantType.QInt8, weight_type=QuantType.QInt8,
                        calibrate_method=CalibrationMethod.MinMax, nodes_to_exclude=exclude)
        if q_src != f32:
            os.remove(q_src)
        if a.int8_form == "float-residual":
            float_residual(i8)
        elif a.int8_form == "conv-inputs":
            conv_inputs_only(i8)
        if chain is not None:
            ins = chain.inputs(role)
            for name, changed, before, after in gptq.round_block(i8, q_blk, ins):
                print(f"{stem} {name}: GPTQ moved {changed:.1%} of the levels; output error "
                      f"{before:.2e} -> {after:.2e} of |W x|", flush=True)
        for path in (f32, i8):
            # Intermediate shape annotations name the batch symbolically; a
            # runtime that fixes the input shapes (tract) infers them anew.
            mo = onnx.load(path)
            del mo.graph.value_info[:]
            onnx.save(mo, path)
        if chain is not None:
            chain.advance(role, i8, ins, q_blk)
        fp32_files.append(f32)
        int8_files.append(i8)
        blocks.append({"role": role, "index": i, "aux_channels": blk.aux_channels})
        print(f"exported {stem}", flush=True)

    # Fixtures: validation slices, raw log sinograms as the firmware gets them.
    val = Split(a.data, "validation", level)
    fx_idx = np.linspace(0, val.n - 1, a.fixtures + 2).astype(int)[1:-1]
    fixtures = []
    for k, j in enumerate(fx_idx):
        graw, mraw, xraw = val.batch([j])
        g, m, _ = tensors((graw, mraw, xraw), stats)
        with torch.no_grad():
            ref = (net(g, m) * stats["x_scale"]).numpy()[0, 0]
        ref8 = (run_onnx_chain(int8_files, op, g, m, net.n_blocks, use_mask) * stats["x_scale"]).numpy()[0, 0]
        thickness = val.split["slices"][int(j)]["thickness_mm"]
        stem = f"case{k}"
        files = {}
        for name, arr in (("sinogram", graw[0]), ("truth", xraw[0]), ("torch_fp32", ref), ("ort_int8", ref8)):
            p = os.path.join(a.out, "fixtures", f"{stem}-{name}.f32")
            np.asarray(arr, dtype="<f4").tofile(p)
            files[name] = os.path.relpath(p, a.out)
        fixtures.append({"name": stem, "thickness_mm": thickness, "validation_slice": int(j),
                         "files": files,
                         "int8_vs_fp32_max_abs_per_mm": float(np.abs(ref8 - ref).max())})
        print(f"fixture {stem}: int8 vs fp32 max abs {np.abs(ref8 - ref).max():.3e} /mm", flush=True)

    # The trainer's own records of this run, so that the folder never ships a
    # stale curve or options (every file in it is hashed below).
    for rec in ("curve.csv", "run.json"):
        if os.path.exists(os.path.join(a.run, rec)):
            shutil.copyfile(os.path.join(a.run, rec), os.path.join(a.out, rec))

    everything = []
    for root, _, names in os.walk(a.out):
        for n in sorted(names):
            p = os.path.join(root, n)
            if os.path.relpath(p, a.out) != "manifest.json":
                everything.append(os.path.relpath(p, a.out))
    manifest = {
        "format": "dbtor-model/1",
        "name": a.name or os.path.basename(os.path.normpath(a.out)),
        "kind": kind,
        "geometry": run["geometry"],
        "state_channels": STATE,
        "channels": {"output": 0, "projected": 1, "backprojected": 0},
        "block_inputs": ({"dual": ["h (5)", "P(f[1])", "g", "P(m)"], "primal": ["f (5)", "P*(h[0])", "m"]}
                         if use_mask else {"dual": ["h (5)", "P(f[1])", "g"], "primal": ["f (5)", "P*(h[0])"]}),
        "normalisation": {
            "g_mean": stats["g_mean"], "g_std": stats["g_std"], "x_scale_per_mm": stats["x_scale"],
            "operator_norm": op.norm,
            "rule": "g_n = (g - g_mean) / g_std; the network's P and P* are divided by operator_norm; "
                    + ("mask m is 0/1 on the image grid (rows within the thickness above the bottom row); "
                       if use_mask else "no mask (LPD); ")
                    + "output image (1/mm) = f[0] * x_scale_per_mm",
        },
        "opset": OPSET,
        "blocks": [dict(b, fp32=os.path.relpath(f, a.out), int8=os.path.relpath(q, a.out))
                   for b, f, q in zip(blocks, fp32_files, int8_files)],
        "int8": {"format": "QDQ", "weights": "int8 per channel (symmetric)", "activations": ("int8 per tensor" if a.int8_form != "conv-inputs" else
                                 "int8 per tensor, the convolutions' inputs only; the concatenation "
                                 "prescaled per channel"),
                 "calibration": f"MinMax on {n_cal} training slices", "tool": f"onnxruntime {ort.__version__}",
                 "equalise_alpha": a.equalise, "form": a.int8_form,
                 "weight_rounding": (f"GPTQ on {a.gptq} training slices (seed {gptq.GPTQ_SEED}), damp {gptq.DAMP}, "
                                     "columns by decreasing Hessian diagonal"
                                     + (", asymmetric: the float network's outputs as targets, biases refitted"
                                        if a.gptq_asymmetric else "") if a.gptq else "to the nearest level"),
                 "weights_from": ("the fp32 blocks' run" if ck8 is None else
                                  f"quantisation-aware fine-tuning ({run8['command']}), "
                                  f"{ck8['iteration']} iterations")},
        "fixtures": fixtures,
        "sha256": {p: sha256(os.path.join(a.out, p)) for p in sorted(everything)},
        "provenance": provenance(run, ck, "dbtor.export", argv),
    }
    if source is not None:
        manifest["provenance"] = dict(source["provenance"], export_command=manifest["provenance"]["export_command"],
                                      requantised_from={"model_folder": os.path.abspath(a.from_model),
                                                        "name": source["name"],
                                                        "manifest_sha256": manifest_sha256(a.from_model)})
        manifest["validation"] = source.get("validation")
    if ck8 is not None:
        manifest["provenance"]["int8_run"] = {
            "train_command": run8["command"], "options": run8["options"], "iterations": ck8["iteration"],
            "training_minutes": round(ck8["elapsed_s"] / 60, 1), "init": run8.get("init")}
    validation = trainer_validation(a.run, level, "--model" if use_mask else "--lpd")
    if validation:
        manifest["validation"] = validation
    if a.validation:
        with open(a.validation) as f:
            manifest["validation"] = json.load(f)
    with open(os.path.join(a.out, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=2)
    print(f"wrote {a.out}/manifest.json ({len(everything)} files)")


if __name__ == "__main__":
    main()
