"""The paper's U-Net baseline: a U-Net post-processing FBP reconstructions.

Choices written down (the paper gives depth 4, 32 initial filters and instance
normalisation):
- Input: the FBP of the log sinogram (`host-sim fbp`: Hann-windowed ramp, zero
  outside the thickness mask, 1/mm), divided by the training set's image RMS
  `x_scale`, the same unit as the target image.
- Depth 4: four 2x2 max-poolings, so five resolution levels with 32, 64, 128,
  256 and 512 filters. Each level: two Conv3x3 -> InstanceNorm (affine) ->
  ReLU. Up-sampling by a 2x2 transposed convolution, concatenation with the
  skip, two convolutions. A 1x1 convolution gives one channel, added to the
  input (residual learning, as FBPConvNet).
- The image is zero-padded at the bottom/right to a multiple of 16 and the
  output cropped back, inside the network (so the ONNX file takes the model's
  image size as it is).
"""
import torch
import torch.nn.functional as F
from torch import nn

FILTERS = 32
DEPTH = 4


def double_conv(c_in, c_out):
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1),
        nn.InstanceNorm2d(c_out, affine=True),
        nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1),
        nn.InstanceNorm2d(c_out, affine=True),
        nn.ReLU(inplace=True),
    )


class UNet(nn.Module):
    def __init__(self, filters=FILTERS, depth=DEPTH):
        super().__init__()
        self.depth = depth
        ch = [filters * 2 ** k for k in range(depth + 1)]
        self.down = nn.ModuleList([double_conv(1 if k == 0 else ch[k - 1], ch[k]) for k in range(depth + 1)])
        self.up = nn.ModuleList([nn.ConvTranspose2d(ch[k + 1], ch[k], 2, stride=2) for k in range(depth)])
        self.merge = nn.ModuleList([double_conv(2 * ch[k], ch[k]) for k in range(depth)])
        self.out = nn.Conv2d(ch[0], 1, 1)

    def forward(self, x, m=None):
        """x: [B,1,H,W] FBP in units of x_scale; `m` (the mask) is not used.
        Returns the image in units of x_scale."""
        h, w = x.shape[-2:]
        mult = 2 ** self.depth
        ph, pw = (-h) % mult, (-w) % mult
        z = F.pad(x, (0, pw, 0, ph))
        skips = []
        for k in range(self.depth + 1):
            z = self.down[k](z)
            if k < self.depth:
                skips.append(z)
                z = F.max_pool2d(z, 2)
        for k in reversed(range(self.depth)):
            z = self.merge[k](torch.cat([skips[k], self.up[k](z)], 1))
        return x + self.out(z)[..., :h, :w]
