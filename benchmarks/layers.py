"""The autoencoder layers the trainer changed, old against new, forward + backward, in one
process: the conv decoder's last transposed convolution (16 -> C channels, oneDNN's forward
against PyTorch's own forward with oneDNN's backward), the encoder's stages (conv, ReLU,
pool against conv, pool, in-place ReLU), and a whole training step of SINDy-2 with the conv
decoder (loss + backward + AdamW) with all the old layers against the new, at the paper's
batch (500 windows of 2 frames: 1000 images through the encoder, 1500 through the decoder).

Variants are interleaved over ``--rounds`` rounds; each keeps its least wall time and its least
CPU time of this thread (``time.thread_time``, which leaves out time spent waiting for a core
while other jobs run). Also checks that old and new compute the same values.

    .venv/bin/python benchmarks/layers.py --rounds 30
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import torch
from torch import nn

from latent_sindy.models import AutoencoderConfig
from latent_sindy.models.autoencoder import Autoencoder
from latent_sindy.training import core as fit


def last_layer(channels: int) -> tuple[nn.Module, nn.Module, torch.Tensor]:
    torch.manual_seed(0)
    new = Autoencoder(AutoencoderConfig(channels=channels, image_size=32, decoder_kind="conv")
                      ).decoder.conv[2]
    old = nn.ConvTranspose2d(16, channels, 4, stride=2, padding=1)
    old.load_state_dict(new.state_dict())
    old.to(memory_format=torch.channels_last)
    x = torch.randn(1500, 16, 16, 16).contiguous(memory_format=torch.channels_last)
    return old, new, x.requires_grad_()


def encoder_stages() -> tuple[nn.Module, nn.Module, torch.Tensor]:
    torch.manual_seed(0)
    new = Autoencoder(AutoencoderConfig(channels=1, image_size=32)).encoder
    old = nn.Sequential(*new.net)
    old[1], old[2], old[4], old[5] = nn.ReLU(), nn.MaxPool2d(2), nn.ReLU(), nn.MaxPool2d(2)
    x = torch.randn(1000, 1, 32, 32).contiguous(memory_format=torch.channels_last)
    return old, new, x


class Step(nn.Module):
    """One training step of a SINDy-2 conv-decoder model as a module whose output is the
    loss; ``old``: its autoencoder with the layers as they were."""

    def __init__(self, old: bool) -> None:
        super().__init__()
        from latent_sindy.models import LatentModel, ModelConfig, SindyConfig

        torch.manual_seed(0)
        cfg = ModelConfig(observation=AutoencoderConfig(decoder_kind="conv"),
                          dynamics=SindyConfig(order=2)).resolve(1, 32, 3)
        self.model = LatentModel(cfg)
        if old:
            net = self.model.autoencoder.encoder.net
            net[1], net[2], net[4], net[5] = nn.ReLU(), nn.MaxPool2d(2), nn.ReLU(), nn.MaxPool2d(2)
            dec = self.model.autoencoder.decoder
            dec.conv[2].__class__ = nn.ConvTranspose2d
            for m in dec.modules():
                if isinstance(m, nn.ReLU):
                    m.inplace = False
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=1e-3)
        self.u = torch.randn(500, 1, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.opt.step()  # the previous step's update (timed with this one)
        self.opt.zero_grad(set_to_none=True)
        return self.model.loss(x, self.u)["total"]


def timed(f: Callable[[], torch.Tensor], params: list[torch.Tensor]) -> tuple[float, float]:
    for p in params:
        p.grad = None
    w0, c0 = time.perf_counter(), time.thread_time()
    y = f()
    y.backward(torch.ones_like(y))
    return time.perf_counter() - w0, time.thread_time() - c0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=30)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    fit.keep_freed_memory()
    cases = {}
    for c in (1, 3):
        old, new, x = last_layer(c)
        cases[f"last transposed conv 16->{c}"] = (old, new, x)
    cases["encoder (2 conv stages + fc)"] = encoder_stages()
    torch.manual_seed(1)
    cases["training step, SINDy-2 conv"] = (Step(old=True), Step(old=False),
                                            torch.randn(500, 2, 1, 32, 32))
    best: dict[tuple[str, str], list[float]] = {}
    for name, (old, new, x) in cases.items():
        if isinstance(old, Step):
            continue
        with torch.no_grad():
            err = float((old(x) - new(x)).abs().max())
        print(f"{name}: largest difference old - new {err:.1e}")
    for _ in range(args.rounds):
        for name, (old, new, x) in cases.items():
            for which, m in (("old", old), ("new", new)):
                params = ([] if isinstance(m, Step) else  # (a step keeps its gradients)
                          [*m.parameters()] + ([x] if x.requires_grad else []))
                w, c = timed(lambda m=m, x=x: m(x), params)
                b = best.setdefault((name, which), [w, c])
                b[0], b[1] = min(b[0], w), min(b[1], c)
    print(f"\nforward + backward, best of {args.rounds} interleaved rounds, {args.threads} "
          f"thread(s); load average {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print(f"{'layer':<32} {'old ms':>8} {'new ms':>8} {'x':>6} {'old CPU':>8} {'new CPU':>8} "
          f"{'x CPU':>6}")
    for name in cases:
        (wo, co), (wn, cn) = best[(name, "old")], best[(name, "new")]
        print(f"{name:<32} {1e3 * wo:8.1f} {1e3 * wn:8.1f} {wo / wn:6.2f} {1e3 * co:8.1f} "
              f"{1e3 * cn:8.1f} {co / cn:6.2f}")


if __name__ == "__main__":
    main()
