"""DBToR (the paper's Figure 1 / Algorithm 1) and LPD (the same without the mask).

Choices written down (the paper leaves them open):
- State: 5 channels in both the primal (image) and dual (sinogram) spaces, both
  initialised to 0. The dual block sees [h, P(f[1]), g, P(m)] (8 channels), the
  primal block [f, P*(h[0]), m] (7 channels); LPD drops P(m) and m (7 and 6).
  The output is f[0] (the paper's f^(1); channels are 0-based here).
- A block is Conv3x3(c_in, 64) PReLU(64) Conv3x3(64, 64) PReLU(64) Conv3x3(64, 5)
  with zero 'same' padding, PReLU slopes per channel initialised to 0.25, and a
  residual update: state <- state + block(cat(state, aux)).
- Units: the network works with P / ||P|| (operator.py), the normalised
  sinogram (g - g_mean) / g_std and the image in units of x_scale (1/mm); the
  manifest stores the three constants.
"""
import torch
from torch import nn

STATE = 5
HIDDEN = 64


class Block(nn.Module):
    def __init__(self, aux_channels):
        super().__init__()
        self.aux_channels = aux_channels
        self.net = nn.Sequential(
            nn.Conv2d(STATE + aux_channels, HIDDEN, 3, padding=1),
            nn.PReLU(HIDDEN, init=0.25),
            nn.Conv2d(HIDDEN, HIDDEN, 3, padding=1),
            nn.PReLU(HIDDEN, init=0.25),
            nn.Conv2d(HIDDEN, STATE, 3, padding=1),
        )

    def forward(self, state, aux):
        x = torch.cat([state, aux], dim=1)
        if state.is_contiguous(memory_format=torch.channels_last) and state.shape[1] > 1:
            # channels-last in, channels-last through the convolutions (the
            # concatenation of a 1-channel aux may have fallen back to NCHW)
            x = x.contiguous(memory_format=torch.channels_last)
        return state + self.net(x)


class PrimalDual(nn.Module):
    """DBToR when `use_mask`, else LPD."""

    def __init__(self, op, blocks=10, use_mask=True):
        super().__init__()
        self.op = op
        # channels_last(): the state tensors and convolutions in NHWC (the
        # layout oneDNN runs on AMX and AVX-512 BF16); a layout only, the
        # arithmetic and the state_dict are the same
        self.memory_format = torch.contiguous_format
        self.use_mask = use_mask
        self.n_blocks = blocks
        extra = 1 if use_mask else 0
        self.dual = nn.ModuleList([Block(2 + extra) for _ in range(blocks)])
        self.primal = nn.ModuleList([Block(1 + extra) for _ in range(blocks)])

    def forward(self, g, m):
        """g: [B,1,V,D] normalised sinogram; m: [B,1,H,W] mask (0/1).
        Returns f[0] in units of x_scale, [B,1,H,W]."""
        b = g.shape[0]
        h = g.new_zeros(b, STATE, *self.op.sino_shape).contiguous(memory_format=self.memory_format)
        f = g.new_zeros(b, STATE, *self.op.image_shape).contiguous(memory_format=self.memory_format)
        pm = self.op.forward(m) if self.use_mask else None
        for i in range(self.n_blocks):
            pf = self.op.forward(f[:, 1:2])
            aux = torch.cat([pf, g, pm], 1) if self.use_mask else torch.cat([pf, g], 1)
            h = self.dual[i](h, aux)
            bh = self.op.adjoint(h[:, 0:1])
            aux = torch.cat([bh, m], 1) if self.use_mask else bh
            f = self.primal[i](f, aux)
        return f[:, 0:1]

    def channels_last(self):
        """The network in channels-last layout (weights and state); returns
        self."""
        self.memory_format = torch.channels_last
        return self.to(memory_format=torch.channels_last)
