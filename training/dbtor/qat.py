"""Quantisation-aware fine-tuning (`train.py --qat`): every block runs with the
int8 rounding the exported QDQ graph applies, so that the network learns to
live with it.

Measured before this existed (`python -m dbtor.int8_sensitivity` and a
simulation of the same graph in PyTorch, on 16 validation slices of dbtor-x4t
at N8): per-channel int8 weights cost 0.002 dB; the per-tensor int8
activations cost 0.76 dB, spread over every point of the block (0.23 dB the
quantised state alone, 0.28 dB the block output alone, 0.03 to 0.16 dB each
convolution's). Calibration methods (percentile, entropy) did not help, and
keeping the residual sum in float recovered only 0.2 dB. So the rounding
seemed to need learning rather than tuning away. It did not: one run of
this fine-tuning gained about 0.1 dB (models/README.md), while quantising
only the convolutions' inputs (export.py's conv-inputs form, the default
since) brought the simulated loss to 0.12 dB without training. The
fine-tuning stays for models where that is not enough.

The simulated graph is exactly one of the three that `export.py` writes with
onnxruntime's `quantize_static` (QDQ, QInt8 activations, per-channel
symmetric QInt8 weights) and that the Rust fast path runs
(`crates/dbt-dbtor/src/fast.rs`), chosen by `--int8-form`:

    conv-inputs (the default): only the convolutions' inputs are quantised,
      c = DQ(Q(cat(state, aux) * k)); p1 = DQ(Q(prelu1(conv1'(c))));
      p2 = DQ(Q(prelu2(conv2(p1)))); out = state + conv3(p2)
      with k one factor per concatenated channel and conv1' = conv1 with its
      input channels divided by k (the float function unchanged; prescale()).
    float-residual: every activation quantised but the residual,
      s = DQ(Q(state)); a = DQ(Q(aux)); c = DQ(Q(cat(s, a)))
      c1 = DQ(Q(conv1(c))); p1 = DQ(Q(prelu1(c1))); c2 = ...; p2 = ...
      c3 = DQ(Q(conv3(p2))); out = state + c3
    plain: onnxruntime's graph as it makes it, the float-residual one with
      out = DQ(Q(s + c3)).

- Activations: per tensor, asymmetric int8 with the range [min(0, lo),
  max(0, hi)] (onnxruntime's MinMax), `scale = (hi - lo) / 255`,
  `zero_point = round(-128 - lo / scale)` clamped to int8.
- Weights: per output channel, symmetric, `scale = max |w| / 127`.
- Ranges: MinMax over the same calibration slices `export.py` uses
  (`calibration_batches`), measured with the quantisation off
  (`calibrate`), at the start and at every validation of the run, so the
  ranges follow the weights as the export will see them. The prescale k
  comes from the same pass (per-channel ranges of the concatenation).
- Gradients: straight-through (the rounding's gradient is taken as 1).

The checkpoint's state_dict is the plain model's (the ranges are not
persistent buffers), so `export.py` reads a QAT run like any other.
"""
import numpy as np
import torch
import torch.nn.functional as F

from .equalize import prescale
from .model import Block

POINTS = ("state", "aux", "cat", "c1", "p1", "c2", "p2", "c3", "out")
# The int8 graph forms (export.py --int8-form) and the points each quantises.
FORMS = {
    "conv-inputs": ("cat", "p1", "p2"),
    "float-residual": ("state", "aux", "cat", "c1", "p1", "c2", "p2", "c3"),
    "plain": POINTS,
}
CALIBRATION_SEED = 12345


def form_of(int8):
    """The graph form of a manifest's `int8` record (older manifests name
    only the residual, or nothing: onnxruntime's plain graph)."""
    if "form" in int8:
        return int8["form"]
    return "float-residual" if int8.get("residual") == "float" else "plain"


def calibration_batches(split, stats, n):
    """The training slices int8 is calibrated on (export.py and --qat alike),
    normalised, as batches of 4 (g, m)."""
    from .train import tensors

    rng = np.random.default_rng(CALIBRATION_SEED)
    idx = rng.choice(split.n, size=min(n, split.n), replace=False)
    return [tensors(split.batch(idx[s:s + 4]), stats)[:2] for s in range(0, len(idx), 4)]


def fake_quant_activation(x, lo, hi):
    """DQ(Q(x)) of onnxruntime's asymmetric int8, straight-through, in float32
    (under bf16 autocast too). A range of zero width (the zero initial state
    of the first blocks) passes x unchanged, as onnxruntime's scale 1 does to
    zeros."""
    x = x.float()
    lo = torch.clamp(lo, max=0.0)
    hi = torch.clamp(hi, min=0.0)
    width = hi - lo
    scale = torch.where(width > 0, width / 255.0, torch.ones_like(width))
    zp = torch.clamp(torch.round(-128.0 - lo / scale), -128.0, 127.0)
    q = (torch.clamp(torch.round(x / scale) + zp, -128.0, 127.0) - zp) * scale
    return x + (q - x).detach()


def fake_quant_weight(w):
    """Per-output-channel symmetric int8 weights, straight-through."""
    scale = w.detach().abs().amax(dim=(1, 2, 3), keepdim=True) / 127.0
    scale = torch.where(scale > 0, scale, torch.ones_like(scale))
    q = torch.clamp(torch.round(w / scale), -127.0, 127.0) * scale
    return w + (q - w).detach()


class QatBlock(Block):
    """A Block whose forward applies the QDQ graph's rounding (`mode` "quant"),
    records activation ranges ("observe") or runs plain ("float")."""

    def setup(self, compile=False, form="conv-inputs"):
        if form not in FORMS:
            raise ValueError(f"int8 form {form!r}: one of {', '.join(FORMS)}")
        self.mode = "float"
        self.form = form
        self.active = set(FORMS[form])  # the points quantised in mode "quant"
        self.quant_weights = True
        self._quant_forward = torch.compile(self._forward_quant, dynamic=False) if compile else self._forward_quant
        for p in POINTS:
            self.register_buffer(f"lo_{p}", torch.zeros(()), persistent=False)
            self.register_buffer(f"hi_{p}", torch.zeros(()), persistent=False)
        # Per-channel range of the concatenation (conv-inputs: the prescale).
        c = self.net[0].in_channels
        self.register_buffer("cat_lo", torch.zeros(c), persistent=False)
        self.register_buffer("cat_hi", torch.zeros(c), persistent=False)

    def reset_ranges(self):
        for p in POINTS:
            getattr(self, f"lo_{p}").zero_()
            getattr(self, f"hi_{p}").zero_()
        self.cat_lo.zero_()
        self.cat_hi.zero_()

    def prescale(self):
        """k of the conv-inputs form, from the observed concatenation."""
        return prescale(self.cat_lo, self.cat_hi)

    def _q(self, x, p):
        if p not in FORMS[self.form]:
            return x
        if self.mode == "observe":
            lo, hi = getattr(self, f"lo_{p}"), getattr(self, f"hi_{p}")
            lo.copy_(torch.minimum(lo, x.detach().min()))
            hi.copy_(torch.maximum(hi, x.detach().max()))
            return x
        if self.mode == "quant" and p in self.active:
            return fake_quant_activation(x, getattr(self, f"lo_{p}"), getattr(self, f"hi_{p}"))
        return x

    def forward(self, state, aux):
        if self.mode == "float":
            return super().forward(state, aux)
        if self.mode == "quant":
            return self._quant_forward(state, aux)
        return self._forward_quant(state, aux)

    def _forward_quant(self, state, aux):
        conv1, prelu1, conv2, prelu2, conv3 = self.net
        q = self._q
        wq = fake_quant_weight if self.mode == "quant" and self.quant_weights else (lambda w: w)
        s = q(state, "state")
        x = torch.cat([s, q(aux, "aux")], 1)
        w1 = conv1.weight
        if self.form == "conv-inputs" and self.mode == "observe":
            # per channel; the range of cat * k follows once k is known (calibrate)
            d = x.detach()
            self.cat_lo.copy_(torch.minimum(self.cat_lo, d.amin(dim=(0, 2, 3))))
            self.cat_hi.copy_(torch.maximum(self.cat_hi, d.amax(dim=(0, 2, 3))))
        else:
            if self.form == "conv-inputs":
                k = self.prescale().view(1, -1, 1, 1)
                x = x * k
                w1 = w1 / k
            x = q(x, "cat")
        x = q(F.conv2d(x, wq(w1), conv1.bias, padding=1), "c1")
        x = q(prelu1(x), "p1")
        x = q(F.conv2d(x, wq(conv2.weight), conv2.bias, padding=1), "c2")
        x = q(prelu2(x), "p2")
        x = q(F.conv2d(x, wq(conv3.weight), conv3.bias, padding=1), "c3")
        if self.form != "plain":
            return state + x
        return q(s + x, "out")


def qat_blocks(net):
    return [b for b in net.modules() if isinstance(b, QatBlock)]


def enable(net, compile=False, form="conv-inputs"):
    """Turn every Block of `net` into a QatBlock, in place (same parameters);
    `compile`: torch.compile the quantised forward of each; `form`: the graph
    of export.py --int8-form."""
    for b in net.modules():
        if type(b) is Block:
            b.__class__ = QatBlock
            b.setup(compile, form)
    return net


def set_mode(net, mode):
    for b in qat_blocks(net):
        b.mode = mode


def calibrate(net, batches):
    """MinMax ranges of every quantisation point over `batches` of (g, m),
    with the network in float; leaves it quantising."""
    was_training = net.training
    net.eval()
    for b in qat_blocks(net):
        b.reset_ranges()
    set_mode(net, "observe")
    with torch.no_grad():
        for g, m in batches:
            net(g, m)
        for b in qat_blocks(net):
            if b.form == "conv-inputs":
                # MinMax of cat * k, channel by channel (k > 0 keeps the order).
                k = b.prescale()
                b.lo_cat.copy_((b.cat_lo * k).min())
                b.hi_cat.copy_((b.cat_hi * k).max())
    set_mode(net, "quant")
    net.train(was_training)


def main(argv=None):
    """Check that the simulation is the exported graph, block by block: each
    exported int8 block run by onnxruntime against the QatBlock of the same
    weights (equalised and in the graph form the manifest says, ranges
    measured on the export's calibration slices), on the inputs the float
    network feeds that block on validation slices. onnxruntime computes the
    convolutions in integers and requantises them, the simulation in float,
    so an activation may land one step apart where the two fall on either side
    of a rounding boundary, and a block's three convolutions can stack two
    such steps. The limits (at most 2 output steps, at most 5 % of outputs
    off, RMS at most 0.25 steps) sit above what dbtor-x4t's blocks show (2
    steps, 2.1 %, 0.15) and below a simulation missing one quantisation (the
    concatenation's: 24-39 % off, RMS 0.5-0.7 steps). In the conv-inputs form
    the output is a float sum with no step of its own, so there the RMS
    distance of the simulation to onnxruntime is compared with the float
    block's: at most 0.25 (dbtor-x4t's blocks: 0.06-0.15; leaving out one
    of the three quantisations with --omit: 0.30-0.99, over 0.25 in every
    block: cat 0.51-0.99, p1 0.35-0.68, p2 0.30-0.70, with `--omit P
    --max-ratio 100`). Chained over 20 blocks
    such one-step differences grow, as any perturbation of the int8 network
    does, so the whole network is compared by its figures, not value by
    value."""
    import argparse
    import json
    import os

    from .data import Split
    from .equalize import equalise
    from .export import capture_block_inputs
    from .model import PrimalDual
    from .operator import Operator
    from .train import tensors

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("--model", required=True, help="exported model folder (manifest.json)")
    ap.add_argument("--run", required=True, help="the run its int8 blocks were quantised from")
    ap.add_argument("--data", required=True)
    ap.add_argument("--slices", type=int, default=2)
    ap.add_argument("--calibration", type=int, default=16, help="as given to export.py")
    ap.add_argument("--budget", type=int, default=0, metavar="SLICES",
                    help="then score the simulated network on this many validation slices (PSNR and SSIM in "
                         "1/cm against the truth with its range, output masked to the thickness): fp32, int8 "
                         "weights only, all of int8, and each activation point alone")
    ap.add_argument("--max-flips", type=float, default=0.05,
                    help="largest fraction of a block's outputs allowed to differ by a step or more")
    ap.add_argument("--omit", choices=POINTS, default=None,
                    help="leave this quantisation point out of the simulation: the check should then fail "
                         "(how its limits were set)")
    ap.add_argument("--max-ratio", type=float, default=0.25,
                    help="conv-inputs form: largest RMS distance of the simulation to onnxruntime, as a "
                         "fraction of the float block's")
    a = ap.parse_args(argv)
    import onnxruntime as ort

    with open(os.path.join(a.model, "manifest.json")) as f:
        man = json.load(f)
    ck = torch.load(os.path.join(a.run, "checkpoint.pt"), weights_only=False)
    op = Operator(os.path.join(a.data, "operator"))
    use_mask = man.get("kind", "dbtor") == "dbtor"
    net = PrimalDual(op, blocks=ck["blocks"], use_mask=use_mask)
    net.load_state_dict(ck["model"])
    net.eval()
    stats = ck["stats"]
    level = ck["options"]["level"]
    train = Split(a.data, "train", level)
    batches = calibration_batches(train, stats, a.calibration)
    int8 = man.get("int8", {})
    alpha = float(int8.get("equalise_alpha", 0.0))
    if alpha > 0:
        equalise(net, lambda: [net(g, m) for g, m in batches], alpha)
    form = form_of(int8)
    enable(net, form=form)
    if a.omit:
        if a.omit not in FORMS[form]:
            raise SystemExit(f"--omit {a.omit}: the {form} form has no such point ({', '.join(FORMS[form])})")
        for b in qat_blocks(net):
            b.active.discard(a.omit)
    calibrate(net, batches)
    net.eval()
    val = Split(a.data, "validation", level)
    vidx = np.linspace(0, val.n - 1, a.slices + 2).astype(int)[1:-1]
    g, m, _ = tensors(val.batch(vidx), stats)
    set_mode(net, "float")
    _, seen = capture_block_inputs(net, g, m)
    set_mode(net, "quant")
    worst, best = None, None
    for b in man["blocks"]:
        role, i = b["role"], b["index"]
        blk = (net.dual if role == "dual" else net.primal)[i]
        sess = ort.InferenceSession(os.path.join(a.model, b["int8"]), providers=["CPUExecutionProvider"])
        if form == "conv-inputs":
            # The output is a float sum (conv3 of the quantised PReLU): no
            # step to count in. A flip of one PReLU value moves outputs by
            # that step times conv3's weights, a missing quantisation by its
            # rounding everywhere; so the simulation's distance to
            # onnxruntime is compared with the float block's.
            for state, aux in seen[(role, i)]:
                ref = sess.run(None, {"state": state, "aux": aux})[0]
                with torch.no_grad():
                    sim = blk(torch.from_numpy(state), torch.from_numpy(aux)).numpy()
                    blk.mode = "float"
                    flt = blk(torch.from_numpy(state), torch.from_numpy(aux)).numpy()
                    blk.mode = "quant"
                ratio = float(np.sqrt(np.mean((sim - ref) ** 2) / max(np.mean((flt - ref) ** 2), 1e-30)))
                name = f"{role}{i:02d}"
                if worst is None or ratio > worst[1]:
                    worst = (name, ratio)
                if best is None or ratio < best[1]:
                    best = (name, ratio)
                if ratio > a.max_ratio:
                    raise SystemExit(f"{name}: the simulation is {ratio:.3f} as far from onnxruntime's int8 as the "
                                     f"float block (limit {a.max_ratio}); it does not reproduce the exported "
                                     "int8 graph")
            continue
        # The output's step: the last quantisation on the way (the block
        # output, or with a float residual the last convolution's).
        last = "out" if form == "plain" else "c3"
        lo = min(float(getattr(blk, "lo_" + last)), 0.0)
        hi = max(float(getattr(blk, "hi_" + last)), 0.0)
        step = (hi - lo) / 255.0 if hi > lo else 1.0
        for state, aux in seen[(role, i)]:
            ref = sess.run(None, {"state": state, "aux": aux})[0]
            with torch.no_grad():
                sim = blk(torch.from_numpy(state), torch.from_numpy(aux)).numpy()
            d = np.abs(sim - ref) / step
            flips, most, rms = float(np.mean(d > 0.5)), float(d.max()), float(np.sqrt(np.mean(d ** 2)))
            name = f"{role}{i:02d}"
            if worst is None or (most, flips) > (worst[1], worst[2]):
                worst = (name, most, flips)
            if most > 2.0 + 1e-3 or flips > a.max_flips or rms > 0.25:
                raise SystemExit(f"{name}: the simulation differs from onnxruntime by up to {most:.2f} steps, "
                                 f"RMS {rms:.3f} steps, {flips:.2%} of the outputs off by a step or more; "
                                 "it does not reproduce the exported int8 graph")
    if form == "conv-inputs":
        print(f"{len(man['blocks'])} blocks x {len(vidx)} validation slices: the QAT simulation matches "
              f"onnxruntime's int8 within the limits; worst block {worst[0]}: RMS distance {worst[1]:.3f} of "
              f"the float block's (best {best[0]}: {best[1]:.3f}; limit {a.max_ratio})")
    else:
        print(f"{len(man['blocks'])} blocks x {len(vidx)} validation slices: the QAT simulation matches "
              f"onnxruntime's int8 within the limits; worst block {worst[0]}: max {worst[1]:.3f} steps, "
              f"{worst[2]:.2%} of its outputs off by one (limit {a.max_flips:.0%})")
    if a.budget:
        budget(net, val, stats, a.budget)


def budget(net, val, stats, n):
    """Where int8 loses: the simulated network scored with one quantisation
    point at a time (the points of every block together)."""
    from .int8_sensitivity import mean_psnr_ssim
    from .train import tensors

    idx = np.linspace(0, val.n - 1, min(n, val.n)).astype(int)
    g, m, x = tensors(val.batch(idx), stats)
    truth = x.numpy()[:, 0].astype(np.float64) * stats["x_scale"] * 10.0
    mask = m.numpy()[:, 0]

    def score(mode, points, weights):
        for b in qat_blocks(net):
            b.active, b.quant_weights = set(points), weights
        set_mode(net, mode)
        with torch.no_grad():
            z = net(g, m).numpy()[:, 0].astype(np.float64) * stats["x_scale"] * 10.0 * mask
        return mean_psnr_ssim(z, truth)

    rows = [("fp32", "float", (), False), ("int8 weights only", "quant", (), True),
            ("int8 (weights and activations)", "quant", POINTS, True)]
    rows += [(f"activation {p} only", "quant", (p,), False) for p in POINTS]
    form = qat_blocks(net)[0].form
    print(f"{len(idx)} validation slices; int8 form {form} (points: {', '.join(FORMS[form])})")
    print(f"{'simulated':<34} {'PSNR':>6} {'loss':>6} {'SSIM':>6}")
    base = None
    for label, mode, points, weights in rows:
        if len(points) == 1 and points[0] not in FORMS[form]:
            continue
        p, ss = score(mode, points, weights)
        base = p if base is None else base
        print(f"{label:<34} {p:6.2f} {base - p:6.2f} {ss:6.3f}", flush=True)
    for b in qat_blocks(net):
        b.active, b.quant_weights = set(POINTS), True


if __name__ == "__main__":
    main()
