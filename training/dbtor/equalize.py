"""Cross-layer equalisation of the int8 export (Nagel et al., "Data-free
quantization through weight equalization and bias correction", ICCV 2019):
a function-preserving rescaling of each block's hidden channels, so that one
int8 scale per tensor fits all 64 of them.

Why: the exported int8 graph quantises every activation with one scale per
tensor (onnxruntime's static QDQ, and the Rust fast path). The 64 hidden
channels of a block span very different ranges, so the per-tensor step that
covers the widest leaves the narrow ones a few levels. A PyTorch simulation
of the exact QDQ graph (qat.py) on 16 validation slices of dbtor-x4t at N8
put the cost of int8 at 0.76 dB PSNR, of which per-channel scales on all
activations would recover all but 0.13 dB.

How: PReLU is positively homogeneous per channel (prelu(x / s) = prelu(x) / s
for s > 0, the slope unchanged), so dividing output channel c of conv1 (weights
and bias) by s_c and multiplying input channel c of conv2 by s_c leaves the
block's float function unchanged; the same between conv2 and conv3. With
s_c = (m_c / max_k m_k) ** alpha, m_c the largest |value| of channel c on the
calibration slices, alpha = 1 gives every channel the widest one's range
(activations equalised fully), alpha = 1/2 splits the rescaling between the
activations and the next convolution's weights (whose per-output-channel
int8 scale is set by their largest input channel).

The concatenation (5 state and 2-3 aux channels) is the first convolution's
input. Its channels span very different ranges too (dbtor-x4t's dual09: the
aux 40 times narrower than the state). Where the residual sum reads the
state unquantised (export.py's float-residual and conv-inputs forms), the
concatenation feeds nothing but conv1, so the conv-inputs form multiplies it
by one factor per channel, `k_c = 1 / max |x_c|` (`prescale`), before
quantising it, and divides conv1's input channel c by k_c: every channel
then spans [-1, 1] at most, and the float function is unchanged.
"""
import torch

from .model import Block


def hidden_ranges(blocks, run_batches):
    """Per-channel max |value| of each block's two hidden convolution outputs
    (conv1 and conv2, before PReLU) over `run_batches()` (which runs the
    network); returns {block: (m1, m2)}."""
    found = {}
    hooks = []
    for b in blocks:
        for k, conv in ((0, b.net[0]), (1, b.net[2])):
            def hook(mod, args, out, b=b, k=k):
                m = out.detach().abs().amax(dim=(0, 2, 3))
                pair = found.setdefault(b, [None, None])
                pair[k] = m if pair[k] is None else torch.maximum(pair[k], m)
            hooks.append(conv.register_forward_hook(hook))
    try:
        with torch.no_grad():
            run_batches()
    finally:
        for h in hooks:
            h.remove()
    return {b: tuple(v) for b, v in found.items()}


def prescale(lo, hi):
    """k_c = 1 / max(|lo_c|, |hi_c|) of a per-channel range; 1 for a channel
    that is always 0 (the zero state of the first blocks). float32."""
    m = torch.maximum(lo.abs(), hi.abs()).float()
    return torch.where(m > 0, 1.0 / torch.where(m > 0, m, torch.ones_like(m)), torch.ones_like(m))


def scales(m, alpha):
    """s_c = (m_c / max m) ** alpha; 1 for a channel that never fires."""
    top = m.max()
    s = torch.where(m > 0, (m / top) ** alpha, torch.ones_like(m))
    return s if top > 0 else torch.ones_like(m)


@torch.no_grad()
def equalise(net, run_batches, alpha=1.0):
    """Rescale every Block of `net` in place (float function unchanged to
    rounding); returns the number of blocks equalised."""
    blocks = [b for b in net.modules() if isinstance(b, Block)]
    ranges = hidden_ranges(blocks, run_batches)
    for b in blocks:
        conv1, _, conv2, _, conv3 = b.net
        for m, (a, nxt) in zip(ranges[b], ((conv1, conv2), (conv2, conv3))):
            s = scales(m, alpha)
            a.weight.div_(s.view(-1, 1, 1, 1))
            a.bias.div_(s)
            nxt.weight.mul_(s.view(1, -1, 1, 1))
    return len(blocks)
