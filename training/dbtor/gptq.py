"""GPTQ rounding of the int8 export's weights (issue #29 point 3).

Why: with round-to-nearest int8 weights the shipped dbtor-x4t3 reads breasts
1.7 % lower and with 5 % less contrast than its fp32 blocks (64 validation
slices, slope of int8 on fp32 0.947), and its int8 graph with only the
weights quantised does the same (-1.8 %, 0.951): the drift is the weights'
rounding, not the activations' (`python -m dbtor.int8_drift`,
models/README.md). Rounding each weight to its nearest level is unbiased
weight by weight, but a convolution sums hundreds of them against inputs
that are far from zero-mean and strongly correlated, so the errors do not
cancel in the output, and twenty blocks in a loop carry them on.

What: GPTQ (Frantar, Ashkboos, Hoefler & Alistarh, "GPTQ: Accurate
Post-Training Quantization for Generative Pre-trained Transformers", ICLR
2023), itself Optimal Brain Quantization (Frantar & Alistarh 2022) made
column by column: for one convolution with float weights `W` (rows: output
channels; columns: its `c_in x 3 x 3` inputs) and the Hessian
`H = sum_x x x^T` of its input patches on calibration data, the columns are
rounded one at a time (the largest `H_jj` first, GPTQ's "act-order"), and
each column's rounding error is spread over the columns not yet rounded so
as to keep `W x` (not `W`) where it was, through the upper Cholesky factor of
`H^-1` (dampened by 1 % of its mean diagonal, the paper's default). The
per-output-channel scales stay onnxruntime's (`max |w| / 127`), levels are
clamped to [-127, 127], so the graph, its scales, every runtime and the Rust
fast path are unchanged: only which int8 level each weight takes.

The inputs `x` are what the int8 graph really feeds each convolution: the
block's inputs from the int8 chain itself (every block before it already
rounded by GPTQ, run by onnxruntime), the concatenation prescaled and
quantised, and each hidden activation after the previous convolution's new
weights, PReLU and its quantisation, exactly as the conv-inputs graph
computes them (`qat.py`'s formulas). The calibration slices are training
slices (never validation or test), other ones than the activation ranges'.
"""
import numpy as np
import onnx
import onnxruntime as ort
import torch
import torch.nn.functional as F
from onnx import numpy_helper

from .model import STATE

DAMP = 0.01
GPTQ_SEED = 24680
# The levels the Rust fast path accepts for weights (int8/winograd.rs bounds
# |G' g G'^T| with |g| <= 127; onnxruntime's symmetric int8 gives the same).
QMIN, QMAX = -127, 127


def gptq_round(w, h, scale, damp=DAMP, free=0):
    """Integer levels (float64 tensor, rows x columns) for float weights `w`
    [rows, columns] with per-row `scale`, minimising `sum_x |(w - q s) x|^2`
    over the inputs whose second moment is `h` [columns, columns]. The last
    `free` columns (a bias: an input that is always 1) are not rounded but
    take the other columns' errors last; they come back as floats in units
    of `scale`."""
    w = w.double().reshape(w.shape[0], -1).clone()
    h = h.double().clone()
    d = w.shape[1]
    if h.shape != (d, d):
        raise ValueError(f"Hessian {tuple(h.shape)} for {d} weight columns")
    s = scale.double().reshape(-1, 1)
    if not bool(torch.all(s > 0)):
        raise ValueError("a weight scale is not positive")
    dead = torch.diag(h) == 0
    h[dead, dead] = 1.0
    w[:, dead] = 0.0  # inputs that are always zero: any weight does
    r = d - free
    perm = torch.cat([torch.argsort(torch.diag(h)[:r], descending=True), torch.arange(r, d)])
    w, h = w[:, perm], h[perm][:, perm]
    h += damp * torch.mean(torch.diag(h)) * torch.eye(d, dtype=h.dtype)
    u = torch.linalg.cholesky(torch.cholesky_inverse(torch.linalg.cholesky(h)), upper=True)
    q = torch.zeros_like(w)
    for i in range(r):
        col = w[:, i]
        qi = torch.clamp(torch.round(col / s[:, 0]), QMIN, QMAX)
        q[:, i] = qi
        err = (col - qi * s[:, 0]) / u[i, i]
        w[:, i + 1:] -= err[:, None] * u[i, i + 1:][None, :]
    q[:, r:] = w[:, r:] / s
    return q[:, torch.argsort(perm)]


def asymmetric_target(w, b, c, h, damp=DAMP):
    """The weights and bias `[W', b']` that map the int8 network's inputs
    closest to what the float network computes from its own:
    `min |W x_f + b - (W' x_q + b')|^2`, i.e. `[W, b] C H^-1` with
    `C = sum [x_f; 1][x_q; 1]^T` and `H = sum [x_q; 1][x_q; 1]^T` (both
    [columns + 1, columns + 1], the last row and column the constant 1).
    Written `[W, b] + [W, b] (C - H) H^-1`, with `H` dampened in the
    correction only, so that where the int8 inputs are the float ones the
    target is `[W, b]` itself (dampening `[W, b] C H^-1` as a whole would
    shrink the weights along the patches' weak directions: 3x3 neighbours
    are strongly correlated). Returns [rows, columns + 1]."""
    wa = torch.cat([w.double().reshape(w.shape[0], -1), b.double().reshape(-1, 1)], 1)
    hd = h.double().clone()
    dead = torch.diag(hd) == 0
    hd[dead, dead] = 1.0
    hd += damp * torch.mean(torch.diag(hd)) * torch.eye(hd.shape[0], dtype=hd.dtype)
    return wa + torch.linalg.solve(hd, (wa @ (c.double() - h.double())).T).T


def patches(x, ones=False):
    """The 3x3 zero-padded patches of `x` [n, c_in, h, w] as columns
    [c_in * 9 (+ 1), n h w], float32 (one batch's products are summed in
    float32, the batches in float64); with `ones` a last row of 1."""
    u = F.unfold(x.float(), 3, padding=1).permute(1, 0, 2)
    u = u.reshape(u.shape[0], -1)
    return torch.cat([u, torch.ones(1, u.shape[1], dtype=u.dtype)]) if ones else u


def patch_moments(xs, c_in, ys=None):
    """`H = sum_x x x^T` of the 3x3 zero-padded patches of every image in
    `xs` ([n, c_in, h, w] each), float64; with `ys` (the float network's
    images, the same shapes) `(H, sum y x^T, sum y y^T)`, each with a
    constant 1 appended to the patches."""
    d = c_in * 9 + (ys is not None)
    h = torch.zeros(d, d, dtype=torch.float64)
    if ys is None:
        for x in xs:
            u = patches(x)
            h += (u @ u.T).double()
        return h
    c, hy = torch.zeros_like(h), torch.zeros_like(h)
    for x, y in zip(xs, ys):
        u, v = patches(x, True), patches(y, True)
        h += (u @ u.T).double()
        c += (v @ u.T).double()
        hy += (v @ v.T).double()
    return h, c, hy


def fake_quant(x, scale, zero_point):
    """DQ(Q(x)) of onnxruntime's int8 (round half to even, as torch.round)."""
    return (torch.clamp(torch.round(x / scale) + zero_point, -128, 127) - zero_point) * scale


class Chain:
    """The int8 network's unrolled loop on GPTQ's calibration batches, advanced
    one exported block at a time with onnxruntime, so each block is rounded
    on the inputs the int8 blocks before it really give it; with
    `asymmetric`, the float network's loop beside it (each block's float
    twin run in PyTorch), whose values are the targets."""

    def __init__(self, op, batches, use_mask=True, asymmetric=False):
        if not use_mask:
            raise ValueError("GPTQ rounding is implemented for DBToR (the masked network)")
        self.op = op
        self.asymmetric = asymmetric
        self.items = []
        for g, m in batches:
            b = g.shape[0]
            it = {"g": g, "m": m, "pm": op.forward(m),
                  "h": torch.zeros(b, STATE, *op.sino_shape), "f": torch.zeros(b, STATE, *op.image_shape)}
            if asymmetric:
                it["hf"], it["ff"] = it["h"].clone(), it["f"].clone()
            self.items.append(it)

    def _aux(self, it, role, sfx):
        if role == "dual":
            return torch.cat([self.op.forward(it["f" + sfx][:, 1:2]), it["g"], it["pm"]], 1)
        return torch.cat([self.op.adjoint(it["h" + sfx][:, 0:1]), it["m"]], 1)

    def inputs(self, role):
        """Per batch, (state, aux) for the next block of `role`, and with
        `asymmetric` the float network's (state, aux) after them."""
        key = "h" if role == "dual" else "f"
        out = []
        for it in self.items:
            e = (it[key], self._aux(it, role, ""))
            if self.asymmetric:
                e += (it[key + "f"], self._aux(it, role, "f"))
            out.append(e)
        return out

    @torch.no_grad()
    def advance(self, role, path, inputs, float_block=None):
        sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        key = "h" if role == "dual" else "f"
        for it, e in zip(self.items, inputs):
            it[key] = torch.from_numpy(sess.run(None, {"state": e[0].numpy(), "aux": e[1].numpy()})[0])
            if self.asymmetric:
                it[key + "f"] = float_block(e[2], e[3])


@torch.no_grad()
def round_block(path, q_blk, inputs):
    """GPTQ-round the three convolutions' int8 weights of the conv-inputs
    graph at `path` in place. `q_blk`: the float block the graph was
    quantised from (`export.Prescaled`: its weights and prescale); `inputs`:
    the batches of `Chain.inputs`. With the float network's inputs there
    (an asymmetric chain), each convolution's target is the float block's
    output on them, and its bias is refitted with its weights
    (`asymmetric_target`). Returns, per convolution, the share of weights
    whose level changed and the RMS output error against the target with
    the nearest levels (and the old bias) and after."""
    mo = onnx.load(path)
    init = {i.name: i for i in mo.graph.initializer}

    def arr(name):
        if name not in init:
            raise ValueError(f"{path}: no initializer {name!r} (not a conv-inputs int8 block)")
        return numpy_helper.to_array(init[name])

    quants = [n for n in mo.graph.node if n.op_type == "QuantizeLinear"]
    if len(quants) != 3:
        raise ValueError(f"{path}: {len(quants)} QuantizeLinear nodes, a conv-inputs block has 3")
    qp = [(float(arr(n.input[1])), int(arr(n.input[2]))) for n in quants]
    convs = [q_blk.net[0], q_blk.net[2], q_blk.net[4]]
    prelus = [q_blk.net[1], q_blk.net[3]]
    asym = len(inputs[0]) == 4
    xs = [fake_quant(torch.cat([e[0], e[1]], 1) * q_blk.prescale, *qp[0]) for e in inputs]
    fs = [torch.cat([e[2], e[3]], 1) * q_blk.prescale for e in inputs] if asym else None
    report = []
    for k, conv in enumerate(convs):
        name = f"net.{2 * k}"
        old = arr(name + ".weight_quantized")
        ws = arr(name + ".weight_scale").astype(np.float64)
        bscale = arr(name + ".bias_quantized_scale").astype(np.float64)
        bold = arr(name + ".bias_quantized")
        w = conv.weight.detach().double().reshape(conv.weight.shape[0], -1)
        b = conv.bias.detach().double()
        c_in = conv.weight.shape[1]
        s = torch.from_numpy(ws).reshape(-1, 1)
        if asym:
            h, c, hf = patch_moments(xs, c_in, fs)
            target = asymmetric_target(w, b, c, h)
            q = gptq_round(target, h, s, free=1)  # the bias column is not rounded
            levels, bias = q[:, :-1], q[:, -1] * s[:, 0]
            wa = torch.cat([w, b[:, None]], 1)
            ref = torch.trace(wa @ hf @ wa.T)

            def out_err(lv, bb):
                # |W x_f + b - (Q s x_q + b')|^2 summed over the inputs, relative to |W x_f + b|^2
                e_ = torch.cat([lv * s, bb[:, None]], 1)
                num = ref - 2 * torch.trace(wa @ c @ e_.T) + torch.trace(e_ @ h @ e_.T)
                return float(torch.sqrt(torch.clamp(num, min=0) / ref))

            bold_f = torch.from_numpy(bold.astype(np.float64) * bscale)
            report.append((name, float((levels.numpy().reshape(old.shape) != old).mean()),
                           out_err(torch.from_numpy(old.astype(np.float64)).reshape(w.shape), bold_f),
                           out_err(levels, bias)))
            new_b = np.round(bias.numpy() / bscale)
            if np.abs(new_b).max() >= 2 ** 31:
                raise ValueError(f"{path}: {name}'s refitted bias overflows its int32 levels")
            init[name + ".bias_quantized"].CopyFrom(numpy_helper.from_array(new_b.astype(np.int32),
                                                                            name + ".bias_quantized"))
            bias_f = torch.from_numpy((new_b * bscale).astype(np.float32))
        else:
            h = patch_moments(xs, c_in)
            levels = gptq_round(w, h, s)

            def out_err(lv):
                e_ = w - lv * s
                return float(torch.sqrt(torch.trace(e_ @ h @ e_.T) / torch.trace(w @ h @ w.T)))

            report.append((name, float((levels.numpy().reshape(old.shape) != old).mean()),
                           out_err(torch.from_numpy(old.astype(np.float64)).reshape(w.shape)), out_err(levels)))
            bias_f = torch.from_numpy((bold.astype(np.float64) * bscale).astype(np.float32))
        new = levels.reshape(old.shape).numpy().astype(np.int8)
        init[name + ".weight_quantized"].CopyFrom(numpy_helper.from_array(new, name + ".weight_quantized"))
        if k < 2:
            wq = torch.from_numpy(new.astype(np.float32) * ws.reshape(-1, 1, 1, 1).astype(np.float32))
            xs = [fake_quant(prelus[k](F.conv2d(x, wq, bias_f, padding=1)), *qp[k + 1]) for x in xs]
            if asym:
                fs = [prelus[k](conv(f)) for f in fs]
    onnx.checker.check_model(mo)
    onnx.save(mo, path)
    return report


def self_test():
    """Checks of `gptq_round` against what it must do (the smoke test runs
    them): with uncorrelated inputs (`H` the identity) it is rounding to the
    nearest level, level for level; with correlated, non-zero-mean inputs,
    like a block's activations, its output error `|(W - Q s) x|` is well
    below the nearest rounding's; levels stay in [QMIN, QMAX]; a Hessian of
    the wrong size is refused."""
    g = torch.Generator().manual_seed(7)
    rows, cols = 16, 72
    w = torch.randn(rows, cols, generator=g, dtype=torch.float64) * 0.1
    s = w.abs().amax(dim=1) / QMAX
    nearest = torch.clamp(torch.round(w / s[:, None]), QMIN, QMAX)
    q = gptq_round(w, torch.eye(cols, dtype=torch.float64), s, damp=0.0)
    assert torch.equal(q, nearest), "GPTQ with H = I is not rounding to the nearest level"
    mix = torch.randn(cols, 8, generator=g, dtype=torch.float64)
    x = mix @ torch.randn(8, 4000, generator=g, dtype=torch.float64) + 0.5 \
        + 0.05 * torch.randn(cols, 4000, generator=g, dtype=torch.float64)
    h = x @ x.T

    def err(levels):
        return float(torch.linalg.norm((w - levels * s[:, None]) @ x) / torch.linalg.norm(w @ x))

    q = gptq_round(w, h, s)
    assert q.min() >= QMIN and q.max() <= QMAX
    assert torch.equal(q, torch.round(q))
    e_near, e_gptq = err(nearest), err(q)
    assert e_gptq < 0.5 * e_near, f"GPTQ's output error {e_gptq:.3e} is not well below nearest's {e_near:.3e}"
    # A bias column (an input that is always 1) stays a float and takes the
    # weights' errors: the output error falls below keeping the bias as it was.
    b = 0.01 * torch.randn(rows, 1, generator=g, dtype=torch.float64)
    x1 = torch.cat([x, torch.ones(1, x.shape[1], dtype=x.dtype)])
    w1 = torch.cat([w, b], 1)
    q1 = gptq_round(w1, x1 @ x1.T, s, free=1)
    assert torch.equal(q1[:, :-1], torch.round(q1[:, :-1])) and not torch.equal(q1[:, -1], torch.round(q1[:, -1]))

    def err1(levels, bias):
        return float(torch.linalg.norm(w1 @ x1 - torch.cat([levels * s[:, None], bias], 1) @ x1)
                     / torch.linalg.norm(w1 @ x1))

    e_kept, e_free = err1(gptq_round(w, h, s), b), err1(q1[:, :-1], (q1[:, -1] * s)[:, None])
    assert e_free < e_kept, f"the free bias column did not help: {e_free:.3e} against {e_kept:.3e}"
    # The asymmetric target is the float weights themselves when the int8
    # inputs are the float ones (C = H), whatever the damping.
    t = asymmetric_target(w, b[:, 0], x1 @ x1.T, x1 @ x1.T)
    assert torch.allclose(t, w1, rtol=0, atol=1e-12), "the asymmetric target moved without an input error"
    try:
        gptq_round(w, torch.eye(cols - 1, dtype=torch.float64), s)
    except ValueError as e:
        assert "Hessian" in str(e)
    else:
        raise AssertionError("a Hessian of the wrong size was accepted")
    print(f"gptq self-test: H = I gives the nearest levels; correlated inputs: output error "
          f"{e_near:.3e} (nearest) -> {e_gptq:.3e} (GPTQ); a free bias column {e_kept:.3e} -> {e_free:.3e}")


if __name__ == "__main__":
    self_test()
