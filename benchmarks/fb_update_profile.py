"""Where the CPU preset's FB update spends its time: updates/s and XLA's GFLOP per update
of the Four-Rooms FB CPU preset with one of its levers switched back at a time, beside
the f32 matmul peak measured in the same run (1 seed, FB phase; the peak is the best
of `throughput.matmul_rates`).

    python benchmarks/fb_update_profile.py
"""

from __future__ import annotations

import sys

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from throughput import matmul_rates, updates  # noqa: E402

VARIANTS = {
    "cpu preset": {},
    "splus=batch": dict(splus="batch"),
    "q_loss_coef=0": dict(q_loss_coef=0.0),
    "target_policy=greedy": dict(target_policy="greedy"),
    "f_heads=2": dict(f_heads=2),
    "batch_size=1024": dict(batch_size=1024),
    "f_hidden=(1024,)": dict(f_hidden=(1024,)),
}


def main():
    peak = max(matmul_rates().values())
    print(f"f32 matmul peak through XLA (the best of `matmul_rates`, this run): {peak:,.0f} GFLOP/s\n")
    print("| fb, fourrooms, 1 seed | updates/s | GFLOP / update | of matmul peak |\n|---|---|---|---|")
    for name, over in VARIANTS.items():
        rate, gflop = updates("fb", 1, 200, "cpu", **over)
        print(f"| {name} | {rate:,.1f} | {gflop:.2f} | {rate * gflop / peak:.0%} |", flush=True)


if __name__ == "__main__":
    main()
