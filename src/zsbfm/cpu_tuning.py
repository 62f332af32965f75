"""CPU settings for the compiled training loops: one BLAS thread, XLA's own dot emitter, and
JAX's random-bit hash unrolled.

All measured on the 2-core CPU, Four-Rooms CPU presets, one seed (docs/results.md,
"Throughput"); none changes the maths (or a single random bit).

One OpenBLAS thread (set on `import zsbfm`). XLA's CPU backend runs `jnp.linalg.solve`
(the FB Q-loss's 100x100 LU in `agents/fb.py`, the SF baselines' ridge solve in
`agents/sf.py`) through scipy's OpenBLAS LAPACK, from inside an update that XLA already
runs on every core. OpenBLAS then starts its own threads, which spin and fight XLA's for the
same cores: the whole FB update ran at 50 instead of 80 updates/s. An OPENBLAS_NUM_THREADS
the user set is kept as it is.

No YNNPACK fusions (`compiler_options()`, passed to the jit of each training chunk). XLA
0.10 hands dots and their neighbours to the YNNPACK library by default; for the updates'
small matmuls (batch 256-1024, widths 256-1024) XLA's own fused loops are faster: 1.25-1.42x
the updates/s of every algo's FB phase, the same for the belief encoder's phase. Not under
`--xla_backend_optimization_level=0` (the test suite's fast-compile flag), where XLA's own
loops are unoptimised and the library's dots are 1.4x faster.

Threefry unrolled (set on `import zsbfm`). On the CPU, JAX lowers its random-bit hash
(threefry2x32, 20 rounds) as a 5-trip while loop; every key split and draw of an update is
one such loop (about 20 per FB update), and XLA's CPU runtime pays a dispatch per trip. The
unrolled lowering JAX uses on GPUs computes the same bits with no loop: 1.01-1.07x the
updates/s of the CPU presets (1.23x once for bfb), no slower to compile.
"""

from __future__ import annotations

import os
import re

BLAS_VAR = "OPENBLAS_NUM_THREADS"
YNN_OPTION = "xla_cpu_experimental_ynn_fusion_type"


def limit_blas_threads() -> None:
    """Use one OpenBLAS thread unless OPENBLAS_NUM_THREADS is set: the environment variable
    covers BLAS libraries loaded later (scipy's, loaded on the first solve), threadpoolctl
    those already loaded (numpy's, or scipy's when imported before zsbfm)."""
    if BLAS_VAR in os.environ:
        return
    os.environ[BLAS_VAR] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


def unroll_threefry() -> None:
    """Lower threefry2x32 on the CPU with JAX's unrolled rule (the GPU default) instead of
    its rolled loop: the same bits, no while loop. JAX's private lowering table is pinned by
    pyproject's jax==0.10.2; under another JAX without it, JAX's own lowering stays."""
    try:
        from jax._src.interpreters import mlir
        from jax._src.random import threefry2x32 as threefry
        rule, primitive = threefry._threefry2x32_lowering_rule, threefry.threefry2x32_p
    except (ImportError, AttributeError):
        return
    mlir.register_lowering(primitive, rule, platform="cpu")


def compiler_options() -> dict[str, str]:
    """XLA options for a compiled training loop: {} (the defaults) off the CPU, under
    --xla_backend_optimization_level=0, or when XLA_FLAGS chooses the YNNPACK fusions
    itself; else YNNPACK fusions off (an empty list of fusion types)."""
    import jax

    flags = os.environ.get("XLA_FLAGS", "")
    if jax.default_backend() != "cpu" or YNN_OPTION in flags or re.search(r"backend_optimization_level=0\b", flags):
        return {}
    return {YNN_OPTION: ""}
