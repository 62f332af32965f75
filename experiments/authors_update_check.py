"""One FB update of zsbfm and of the authors' code on the same batch, z, h and parameters.

    python experiments/authors_update_check.py --authors-repo /path/to/BeliefConditionedFB

The authors' public JAX code (github.com/skylooop/BeliefConditionedFB) is imported from
--authors-repo at run time (a checkout; it needs `jaxtyping` importable, e.g. `pip install
--target DIR jaxtyping` and --extra-path DIR); nothing of it is part of zsbfm. Both sides
get zsbfm's `size="authors"` Belief-FB parameters (F and B mapped into their layout: their
F's output is d x |A|, zsbfm's |A| x d), one batch of 1024 Four-Rooms transitions from
zsbfm's data, one z per row (sphere / B(s) mix) and one h per row. Printed: each loss
term, the target measure's mean, and the gradient of every F and B tensor (relative
difference, global norms), once with the target networks equal to the online ones (as both
codes start) and once with a perturbed target.
"""

from __future__ import annotations

import argparse
import json
import sys

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.agents.base import Task
from zsbfm.data.collect import collect
from zsbfm.data.samplers import sample_transitions
from zsbfm.ops.sphere import sample_sphere


def authors_agent(repo: str, extra_paths: list[str], cfg):
    sys.path.insert(0, repo)
    sys.path.extend(extra_paths)
    if not hasattr(jax, "tree_map"):  # their code calls jax.tree_map (removed from recent JAX)
        jax.tree_map = jax.tree.map
    from agents.dynamics_fb import ForwardBackwardAgent  # noqa: E402  (the authors' module)

    config = dict(discrete=True, z_dim=cfg.d, f_hidden_dims=list(cfg.f_hidden), f_layer_norm=True,
                  b_hidden_dims=list(cfg.b_hidden), b_layer_norm=True, use_context=True, output_dim=cfg.context_dim,
                  n_blocks=cfg.enc_layers, n_heads=cfg.enc_heads, emb_dim=cfg.enc_embed, mlp_dim=cfg.enc_mlp,
                  context_len=cfg.context_len, world_pred_hidden=list(cfg.pred_hidden), lr=cfg.lr,
                  discount=cfg.gamma, tau=cfg.tau, z_mix_ratio=cfg.z_mix, boltzmann=True,
                  number_of_meta_envs=cfg.n_train_layouts)
    return ForwardBackwardAgent.create(0, np.zeros((1, 2), np.float32), np.full((1,), 3), config)


def to_authors(F, B, n_actions: int, d: int) -> tuple[dict, dict]:
    """zsbfm's F and B parameters in the authors' layout ({"forward_map": ...}, {"backward_map": ...})."""
    trunk = dict(F["params"]["F"]["trunk"])
    last = f"Dense_{len([k for k in trunk if k.startswith('Dense')]) - 1}"

    def reorder(x):  # output unit a * d + i (zsbfm) -> i * |A| + a (theirs)
        lead = x.shape[:-1]
        return x.reshape(*lead, n_actions, d).swapaxes(-1, -2).reshape(*lead, d * n_actions)

    trunk[last] = {k: reorder(v) for k, v in trunk[last].items()}
    return {"forward_map": trunk}, {"backward_map": dict(B["params"]["NormedMLP_0"])}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--authors-repo", required=True, help="a checkout of skylooop/BeliefConditionedFB")
    p.add_argument("--extra-path", nargs="*", default=[], help="more sys.path entries (e.g. where jaxtyping is)")
    p.add_argument("--out", default="")
    a = p.parse_args()

    cfg = zsbfm.Config.preset("fourrooms", "bfb", "authors")
    env = zsbfm.make_env("fourrooms", n_train=cfg.n_train_layouts)
    agent = make_agent(cfg, env)
    k_init, k_data, k_batch, k_z, k_h, k_mix, k_perturb = jax.random.split(jax.random.PRNGKey(0), 7)
    state = agent.init(k_init)
    data = collect(env, k_data, env.contexts("train"), 100)
    batch = sample_transitions(k_batch, data, cfg.batch_size)
    n = cfg.batch_size
    z_sphere = sample_sphere(k_z, n, cfg.d)
    z = jnp.where((jax.random.uniform(k_mix, (n,)) < 0.5)[:, None], z_sphere,
                  agent.backward(state.params.B, batch.obs[::-1]))
    h = jax.random.normal(k_h, (n, cfg.context_dim))
    task = Task(z=z, h=h)

    theirs = authors_agent(a.authors_repo, a.extra_path, cfg)
    rows = {}
    for label, target in (("target = online", state.params),
                          ("perturbed target", jax.tree_util.tree_map(
                              lambda x: x * (1.0 + 0.05 * jax.random.normal(k_perturb, x.shape)), state.params))):
        def ours(params):
            return agent.loss(params, target, batch, task, {})

        (loss, m), g = jax.value_and_grad(ours, has_aux=True)(state.params)
        f_on, b_on = to_authors(state.params.F, state.params.B, env.n_actions, cfg.d)
        f_tg, b_tg = to_authors(target.F, target.B, env.n_actions, cfg.d)
        params = dict(theirs.network.params, modules_f_value=f_on, modules_b_value=b_on,
                      modules_target_f_value=f_tg, modules_target_b_value=b_tg)
        network = theirs.network.replace(params=params)
        agent_t = theirs.replace(network=network)
        tb = {"observations": np.asarray(batch.obs), "next_observations": np.asarray(batch.next_obs),
              "actions": np.asarray(batch.action)}

        def theirs_loss(params):
            return agent_t.fb_loss(tb, z, h, params, jax.random.PRNGKey(0))

        (loss_t, info_t), g_t = jax.value_and_grad(theirs_loss, has_aux=True)(params)
        gF, gB = to_authors(g.F, g.B, env.n_actions, cfg.d)
        diffs = {}
        for name, mine, other in (("F", gF["forward_map"], g_t["modules_f_value"]["forward_map"]),
                                  ("B", gB["backward_map"], g_t["modules_b_value"]["backward_map"])):
            for path, x in jax.tree_util.tree_leaves_with_path(mine):
                y = other
                for k in path:
                    y = y[k.key]
                key = name + "/" + "/".join(k.key for k in path)
                diffs[key] = float(jnp.linalg.norm(x - y) / (jnp.linalg.norm(y) + 1e-30))
        norm = lambda t: float(jnp.sqrt(sum(jnp.sum(x**2) for x in jax.tree_util.tree_leaves(t))))
        rows[label] = {
            "zsbfm": {"total": float(loss), "fb_offdiag": float(m["fb_offdiag"]), "fb_diag": float(m["fb_diag"]),
                      "ortho": float(m["ortho_loss"]), "M_head_gap": float(m["M_head_gap"]),
                      "grad_norm_F": norm(g.F), "grad_norm_B": norm(g.B)},
            "authors": {"total": float(loss_t), "fb_offdiag": float(info_t["fb_offdiag_loss"]),
                        "fb_diag": float(info_t["fb_diag_loss"]),
                        "ortho": float(loss_t - info_t["fb_offdiag_loss"] - info_t["fb_diag_loss"]),
                        "grad_norm_F": norm(g_t["modules_f_value"]), "grad_norm_B": norm(g_t["modules_b_value"])},
            "max_relative_grad_difference": max(diffs.values()),
            "worst_tensor": max(diffs, key=diffs.get),
        }
        print(label, json.dumps(rows[label], indent=1), flush=True)
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
