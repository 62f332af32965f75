"""XLA's YNNPACK fusions on or off (zsbfm/cpu_tuning.py): updates/s of each algo's CPU-preset
chunk, compiled twice in one process (XLA's default options, then zsbfm's), timed in
alternation, best of two rounds; the encoder phase too for the belief algos.

    python benchmarks/compiler_options_ab.py [fb bfb rfb oracle hilp lap]
"""

from __future__ import annotations

import sys

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from throughput import fb_phase_chunk, timed, timing_config  # noqa: E402

from zsbfm.cpu_tuning import YNN_OPTION  # noqa: E402

STEPS = 200
OPTIONS = {"default": {}, "ynnpack off": {YNN_OPTION: ""}}


def main(algos):
    print(f"| updates/s, fourrooms cpu preset, 1 seed | {' | '.join(OPTIONS)} | ratio |\n|---|---|---|---|")
    for algo in algos:
        cfg = timing_config(algo, 1, STEPS)
        phases = {"FB phase": None} | ({"encoder phase": 0} if algo in ("bfb", "rfb") else {})
        for phase, chunk in phases.items():
            compiled, args = fb_phase_chunk(cfg, chunk, OPTIONS)[3:]
            rate = dict.fromkeys(OPTIONS, 0.0)
            for _ in range(2):
                for name, fn in compiled.items():
                    rate[name] = max(rate[name], STEPS / timed(lambda: fn(*args), repeat=3))
            a, b = rate.values()
            print(f"| {algo}, {phase} | {a:.1f} | {b:.1f} | {b / a:.2f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["fb", "bfb", "rfb", "oracle", "hilp", "lap"])
