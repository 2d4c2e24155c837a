"""The training pixels' mean and std (``SequenceData.pixel_stats``, what every data file and
learned-latent fit normalises with) against the same statistics of the whole split in one
float64 array, the way they were computed before: time and the memory each adds.

    python benchmarks/pixel_stats.py                  # 90 sequences of 126 6x64x64 frames
    python benchmarks/pixel_stats.py --sequences 30

The library's way runs first: a process's peak memory only grows, so each figure is the
peak it adds over what came before.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from latent_sindy.data.sequence import SequenceData


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sequences", type=int, default=90)
    args = p.parse_args(argv)
    n = args.sequences
    images = np.random.default_rng(0).integers(0, 256, (n, 126, 6, 64, 64), dtype=np.uint8)
    split = (np.arange(n) >= int(0.8 * n)).astype(np.uint8)  # 80% training
    data = SequenceData.__new__(SequenceData)  # the statistics need only these two fields
    data.images, data.split_ids = images, split

    before, t = peak_mb(), time.perf_counter()
    ours = data.pixel_stats()
    ours_s, ours_mb = time.perf_counter() - t, peak_mb() - before

    before, t = peak_mb(), time.perf_counter()
    x = images[split == 0].astype(np.float64)
    whole = (float(x.mean()), float(x.std()))
    whole_s, whole_mb = time.perf_counter() - t, peak_mb() - before

    print(f"{n} sequences of 126 6x64x64 uint8 frames ({images.nbytes / 2**20:.0f} MB), "
          f"{int((split == 0).sum())} for training")
    print(f"a sequence at a time: mean {ours[0]:.10g}, std {ours[1]:.10g}; "
          f"{ours_s:.2f} s, {ours_mb:.0f} MB added")
    print(f"the whole split in float64: mean {whole[0]:.10g}, std {whole[1]:.10g}; "
          f"{whole_s:.2f} s, {whole_mb:.0f} MB added")
    print(f"time ratio {whole_s / ours_s:.1f}x; memory ratio "
          f"{whole_mb / max(ours_mb, 1.0):.0f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
