"""One BLAS thread for the LAPACK calls inside compiled updates (set on `import zsbfm`).

XLA's CPU backend runs `jnp.linalg.solve` (the FB Q-loss's 100x100 LU in `agents/fb.py`,
the SF baselines' ridge solve in `agents/sf.py`) through scipy's OpenBLAS LAPACK, from inside an update that XLA already
runs on every core. OpenBLAS then starts its own threads, which spin and fight XLA's for
the same cores: on the 2-core CPU this made the whole FB update 1.6x slower (50 vs 80
updates/s, docs/results.md "Throughput"). One OpenBLAS thread computes the same LU.

An OPENBLAS_NUM_THREADS the user set is kept as it is.
"""

from __future__ import annotations

import os

VAR = "OPENBLAS_NUM_THREADS"


def limit_blas_threads() -> None:
    """Use one OpenBLAS thread unless OPENBLAS_NUM_THREADS is set: the environment variable
    covers BLAS libraries loaded later (scipy's, loaded on the first solve), threadpoolctl
    those already loaded (numpy's, or scipy's when imported before zsbfm)."""
    if VAR in os.environ:
        return
    os.environ[VAR] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
