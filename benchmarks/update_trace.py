"""Per-op time of one preset's compiled updates on the CPU, from a JAX profiler trace.

    python benchmarks/update_trace.py                      # fb, fourrooms, cpu preset
    python benchmarks/update_trace.py --algo fb --size paper --updates 4

Traces one chunk of `--updates` updates (after two warm-up chunks) with
`jax.profiler.trace(..., create_perfetto_trace=True)`, then prints the ops with the most
time per update, each with its output shape and the ops fused into it (read from the
compiled HLO). Times include the profiler's overhead (~1.5x on the small CPU preset).
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import re
import sys
import tempfile

import jax

import zsbfm

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from throughput import fb_phase_chunk  # noqa: E402


def describe(hlo: str, name: str) -> str:
    """'<shape> <op>' of HLO instruction `name`; for a fusion, the ops it holds."""
    m = re.search(r"^\s*(?:ROOT )?%" + re.escape(name) + r" = (\S+) ([\w-]+)\((.*)$", hlo, re.M)
    if not m:  # tuple-shaped results (while loops) hold spaces: name the loop by its source
        loop = re.search(r"^\s*%" + re.escape(name) + r" = .* while\(.*op_name=\"([^\"]*)\"", hlo, re.M)
        return f"while loop of {loop.group(1)}" if loop else ""
    shape, op, rest = m.groups()
    called = re.search(r"calls=%([\w.]+)", rest)
    if called:
        start = hlo.find("%" + called.group(1) + " ")
        body = hlo[start:hlo.find("\n}\n", start)]
        op = "fusion[" + ",".join(sorted(set(re.findall(r"= \S+ ([\w-]+)\(", body)) - {"parameter"})) + "]"
    return f"{shape} {op}"


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--env", default="fourrooms")
    p.add_argument("--algo", default="fb")
    p.add_argument("--size", default="cpu")
    p.add_argument("--updates", type=int, default=100)
    p.add_argument("--top", type=int, default=30)
    a = p.parse_args()
    n = a.updates
    # belief algos keep the preset's share of encoder steps, in whole chunks (Config.preset)
    cfg = zsbfm.Config.preset(a.env, a.algo, a.size, num_seeds=1, chunk_steps=n, steps=10 * n)
    chunk, args = fb_phase_chunk(cfg)[3:]
    for _ in range(2):
        jax.block_until_ready(chunk(*args))
    out = tempfile.mkdtemp(prefix="zsbfm-trace-")
    with jax.profiler.trace(out, create_perfetto_trace=True):
        jax.block_until_ready(chunk(*args))
    hlo = chunk.as_text()
    events = json.load(gzip.open(glob.glob(out + "/**/*perfetto_trace.json.gz", recursive=True)[-1]))
    events = events["traceEvents"] if isinstance(events, dict) else events
    total, wall = collections.Counter(), 0.0
    for e in events:
        if e.get("ph") != "X":
            continue
        if "wait for completion" in e["name"]:
            wall = e["dur"]
        elif not e["name"].startswith("$") and "Thunk" not in e["name"] and "Await" not in e["name"]:
            total[e["name"]] += e.get("dur", 0)
    print(f"{a.algo} {a.env} {a.size}: {wall / 1e3 / n:.2f} ms per update under the profiler "
          f"(trace in {out}); ops by time (a while loop's time includes its body's ops):\n")
    print("| ms / update | op | output, contents |\n|---|---|---|")
    for name, us in total.most_common(a.top):
        print(f"| {us / 1e3 / n:.3f} | {name} | {describe(hlo, name)} |")


if __name__ == "__main__":
    main()
