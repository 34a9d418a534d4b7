"""The multi-tower network (torch; training and export only).

After the paper's Fig. 2: one small CNN encoder shared across the N sampled
frames; small MLP encoders for force and width; a decoder over the frame
features (and the force/width features); and an estimation decoder that also
takes the analytical estimates and ends in logits over the log10 E bins of
:mod:`estimator.inference.distribution` (a predictive distribution per grasp).

Sizes (defaults): the frame encoder is four stride-2 3x3 convolutions (16, 32,
48, 64 channels, batch norm, ReLU) followed by global average and max pooling
(128 features per frame: mean activation tracks the contact's extent, the
maximum its deepest point); force/width and rig 2N + 2 -> 32 -> 32; decoder -> 128 -> 64;
analytical 24 -> 32; estimation decoder 64 (+32) -> 32 -> 90 bins. About 116 k
parameters (0.5 MB of ONNX) and a few million multiply-adds per frame at
64 x 88 px.
"""

from __future__ import annotations

import torch
from torch import nn

from estimator.inference.distribution import N_BINS
from estimator.inference.inputs import Variant

__all__ = ["ComplianceNet"]

ENCODER_CHANNELS = (16, 32, 48, 64)


def _conv(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride=2, padding=1, bias=False), nn.BatchNorm2d(c_out),
                         nn.ReLU(inplace=True))


class FrameEncoder(nn.Module):
    """(B*N, C, h, w) images -> (B*N, 2 * last channels) features."""

    def __init__(self, channels: int, widths: tuple[int, ...] = ENCODER_CHANNELS):
        super().__init__()
        layers, c_in = [], channels
        for c_out in widths:
            layers.append(_conv(c_in, c_out))
            c_in = c_out
        self.convs = nn.Sequential(*layers)
        self.features = 2 * c_in

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = self.convs(images)
        return torch.cat([x.mean(dim=(2, 3)), x.amax(dim=(2, 3))], dim=1)


def _mlp(*sizes: int, dropout: float = 0.0) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        layers.append(nn.ReLU(inplace=True))
        if dropout and i == 0:
            layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


class ComplianceNet(nn.Module):
    """Logits (B, N_BINS) over the log10 E bins from the inputs ``variant`` names, in its order.

    Call it with the tensors of ``variant.input_shapes`` (batch first), positionally:
    ``frames`` (B, N, C, h, w), then ``force_width`` (B, 2N + 2) and ``analytical``
    (B, 24) when the variant reads them.
    """

    def __init__(self, variant: Variant, *, dropout: float = 0.2):
        super().__init__()
        self.variant = variant
        self.encoder = FrameEncoder(variant.channels)
        decoder_in = variant.n_frames * self.encoder.features
        self.force_width = None
        if variant.force_width:
            self.force_width = _mlp(variant.input_shapes["force_width"][0], 32, 32)
            decoder_in += 32
        self.decoder = _mlp(decoder_in, 128, 64, dropout=dropout)
        estimation_in = 64
        self.analytical = None
        if variant.analytical:
            n_features = variant.input_shapes["analytical"][0]
            self.analytical = _mlp(n_features, 32)
            estimation_in += 32
        self.estimation = nn.Sequential(_mlp(estimation_in, 32), nn.Linear(32, N_BINS))

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        named = dict(zip(self.variant.input_shapes, inputs, strict=True))
        frames = named["frames"]
        batch = frames.shape[0]
        features = self.encoder(frames.flatten(0, 1)).reshape(batch, -1)
        if self.force_width is not None:
            features = torch.cat([features, self.force_width(named["force_width"])], dim=1)
        hidden = self.decoder(features)
        if self.analytical is not None:
            hidden = torch.cat([hidden, self.analytical(named["analytical"])], dim=1)
        return self.estimation(hidden)
