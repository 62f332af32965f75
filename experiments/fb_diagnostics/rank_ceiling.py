"""What greedy ascent on the *exact* uniform-walk successor measure reaches, and what is left
of it at rank d with one B shared by all layouts (the ceiling of F^T B at that d).

For each train layout, M = P (I - gamma P_pi)^-1 (free rows and columns); the stacked
[layouts x cells x actions, cells] matrix is truncated to its best rank-d approximation
(SVD), and greedy rollouts of 100 steps from (1, 1) towards every free cell are scored.

    python experiments/fb_diagnostics/rank_ceiling.py [fourrooms|doors]
"""
import sys

import numpy as np

from exact_measure import exact_measure, greedy_dense
from zsbfm.envs.gridworld import FAMILIES, fixed_layout_walls

fam = sys.argv[1] if len(sys.argv) > 1 else "fourrooms"
train, _ = fixed_layout_walls(fam, 20)
S = train.shape[1]
N = S * S
start = FAMILIES[fam].start
for gamma in (0.95, 0.99):
    Ms = [exact_measure(w, gamma) for w in train]
    masks = [np.repeat((~w.reshape(-1)).astype(float), 4) for w in train]
    X = np.concatenate([M.reshape(N * 4, N) * m[:, None] for M, m in zip(Ms, masks)], 0)
    U, sv, Vt = np.linalg.svd(X, full_matrices=False)
    for d in (None, 81, 70, 60, 50, 32):
        Xh = X if d is None else (U[:, :d] * sv[:d]) @ Vt[:d]
        Mh = [Xh[i * N * 4:(i + 1) * N * 4].reshape(N, 4, N) for i in range(len(Ms))]
        dense = np.mean([greedy_dense(M, w, start) for w, M in zip(train, Mh)])
        print(f"{fam} uniform-walk measure, gamma={gamma}, rank {d or 'full'}: greedy dense success {dense:.3f}", flush=True)
