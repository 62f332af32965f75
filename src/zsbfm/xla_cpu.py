"""XLA CPU settings that zsbfm applies when it is imported (before JAX starts a backend).

YNNPACK fusions off (`--xla_cpu_experimental_ynn_fusion_type=`): XLA's CPU backend hands
dots, reductions and elementwise ops to YNNPACK by default. On the 2-core CPU, the FB
updates ran faster with XLA's own emitters and Eigen dots, measured in alternating
processes (docs/results.md, "Throughput"; means of two runs each): the Four-Rooms FB CPU
preset +30% (1 seed) and +23% (3 vmapped seeds), the paper sizes +22%.

The flag is appended to XLA_FLAGS unless XLA_FLAGS already names it (a user's own setting
wins; `--xla_cpu_experimental_ynn_fusion_type=dot,eltwise,reduce`, say, turns YNNPACK back
on). XLA reads XLA_FLAGS once, when the first backend starts: a program that ran a JAX
computation before importing zsbfm keeps the settings it started with.
"""

from __future__ import annotations

import os

YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type"
FLAGS = (YNN_FLAG + "=",)


def apply() -> None:
    """Append FLAGS to XLA_FLAGS, each unless XLA_FLAGS already sets it."""
    current = os.environ.get("XLA_FLAGS", "")
    extra = [f for f in FLAGS if f.split("=")[0] not in current]
    if extra:
        os.environ["XLA_FLAGS"] = " ".join([current, *extra]).strip()
