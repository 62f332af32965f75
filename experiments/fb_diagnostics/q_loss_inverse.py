"""Accuracy of the Q-loss's Newton-Schulz C^-1 on the C of a B being trained.

    python experiments/fb_diagnostics/q_loss_inverse.py

Trains the Four-Rooms FB CPU preset (1 seed) and, at 0, 1000 and 5000 updates, builds the
Q-loss's C = E_rho[B B^T] + 1e-4 tr(C)/d I from the exact s+ weights, prints its spectrum,
and the relative error of the implicit reward r_i = B(s'_i)^T C^-1 z_i (256 dataset next
states, z uniform on the sqrt(d)-sphere) when C^-1 is `spd_inverse` with k steps (float32)
instead of a float64 solve.
"""

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.ops import spd_inverse
from zsbfm.train import make_train, seed_keys

cfg = zsbfm.Config.preset("fourrooms", "fb", "cpu", num_seeds=1, chunk_steps=1000)
tr = make_train(cfg)
carry = jax.jit(jax.vmap(tr.init))(seed_keys(cfg))
ds = jax.jit(jax.vmap(tr.collect_data))(carry)
chunk = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None, None)))
agent, rng = tr.agent, np.random.default_rng(0)
for c in range(2):
    if c in (0, 1):
        params = agent.eval_params(jax.tree_util.tree_map(lambda x: x[0], carry.agent_state))
        rho = np.asarray(agent.dataset_stats(jax.tree_util.tree_map(lambda x: x[0], ds))["rho"], np.float64)
        B = np.asarray(agent.backward(params.B, agent.env.states()), np.float64)
        d = B.shape[1]
        C = np.einsum("m,md,me->de", rho, B, B)
        C += 1e-4 * np.trace(C) / d * np.eye(d)
        eig = np.linalg.eigvalsh(C)
        z = rng.normal(size=(256, d))
        z *= np.sqrt(d) / np.linalg.norm(z, axis=1, keepdims=True)
        B_next = B[rng.choice(np.flatnonzero(rho > 0), 256)]
        exact = np.einsum("nd,nd->n", B_next, np.linalg.solve(C, z.T).T)
        print(f"after {c * cfg.chunk_steps} updates: eigenvalues {eig.min():.1e} .. {eig.max():.2f}")
        for k in (8, 16, 20, 24, 32):
            inv = np.asarray(spd_inverse(jnp.asarray(C, jnp.float32), iters=k), np.float64)
            r = np.einsum("nd,nd->n", B_next, z @ inv)
            print(f"  {k:2d} steps: reward relative error {np.linalg.norm(r - exact) / np.linalg.norm(exact):.1e}")
        C32 = jnp.asarray(C, jnp.float32)
        r = np.einsum("nd,nd->n", B_next, np.asarray(jnp.linalg.solve(C32, jnp.asarray(z.T, jnp.float32)).T, np.float64))
        print(f"  float32 LU solve (the Q-loss before): reward relative error {np.linalg.norm(r - exact) / np.linalg.norm(exact):.1e}")
        P = np.linalg.pinv(C - 1e-4 * np.trace(C) / 1.0001 / d * np.eye(d), rcond=1e-3)
        r = np.einsum("nd,nd->n", B_next, z @ P)
        print(f"  pseudo-inverse without the 1e-4 ridge (float64): reward relative error {np.linalg.norm(r - exact) / np.linalg.norm(exact):.1e}")
    carry, _ = chunk(carry, ds, jnp.int32(c), {})
