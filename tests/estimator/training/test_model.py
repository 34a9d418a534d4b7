"""The network's forward pass for every variant."""

from __future__ import annotations

import itertools

import pytest
import torch

from estimator.inference.distribution import N_BINS
from estimator.inference.inputs import Variant
from estimator.training.model import ComplianceNet

VARIANTS = [
    "+".join([image, *(flag for flag, on in zip(("markers", "fw", "analytical"), flags, strict=True) if on)])
    for image in ("depth", "rgb") for flags in itertools.product((False, True), repeat=3)
]


def _inputs(variant: Variant, batch: int) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    return [torch.randn(batch, *shape, generator=generator) for shape in variant.input_shapes.values()]


@pytest.mark.parametrize("name", VARIANTS)
def test_forward_shape_and_range_for_every_variant(name):
    variant = Variant.parse(name, n_frames=3, size_px=(32, 44))
    model = ComplianceNet(variant).eval()
    with torch.no_grad():
        out = model(*_inputs(variant, 4))
    assert out.shape == (4, N_BINS) and torch.all(torch.isfinite(out))  # logits over the log10 E bins
    probs = torch.softmax(out, dim=1)
    assert torch.allclose(probs.sum(dim=1), torch.ones(4)) and torch.all(probs > 0)


@pytest.mark.parametrize(("n_frames", "size_px"), [(1, (64, 88)), (5, (125, 175))])
def test_frame_count_and_resolution_are_parameters(n_frames, size_px):
    variant = Variant.parse("depth+fw+analytical", n_frames=n_frames, size_px=size_px)
    model = ComplianceNet(variant).eval()
    with torch.no_grad():
        assert model(*_inputs(variant, 2)).shape == (2, N_BINS)
    assert sum(p.numel() for p in model.parameters()) < 200_000  # small enough for ~1 ms per grasp


def test_frames_share_one_encoder_and_inputs_matter():
    variant = Variant.parse("depth+fw+analytical", n_frames=3, size_px=(32, 44))
    model = ComplianceNet(variant).eval()
    frames, fw, analytical = _inputs(variant, 2)
    with torch.no_grad():
        base = model(frames, fw, analytical)
        assert not torch.allclose(base, model(frames, fw, analytical + 1.0))
        assert not torch.allclose(base, model(frames, fw * 2.0, analytical))
        swapped = frames.clone()
        swapped[:, [0, 1]] = frames[:, [1, 0]]
        assert not torch.allclose(base, model(swapped, fw, analytical))  # frame order carries time
    convs = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
    assert len(convs) == 4  # one encoder, not one per frame
