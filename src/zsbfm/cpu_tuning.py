"""CPU settings for the compiled training loops: one BLAS thread, and XLA's own dot emitter.

Both measured on the 2-core CPU, Four-Rooms CPU presets, one seed (docs/results.md,
"Throughput"); neither changes the maths.

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


def compiler_options() -> dict[str, str]:
    """XLA options for a compiled training loop: {} (the defaults) off the CPU, under
    --xla_backend_optimization_level=0, or when XLA_FLAGS chooses the YNNPACK fusions
    itself; else YNNPACK fusions off (an empty list of fusion types)."""
    import jax

    flags = os.environ.get("XLA_FLAGS", "")
    if jax.default_backend() != "cpu" or YNN_OPTION in flags or re.search(r"backend_optimization_level=0\b", flags):
        return {}
    return {YNN_OPTION: ""}
