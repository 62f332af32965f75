"""Belief/Rotation-FB pieces against exact facts: vMF moments, Householder, invariances."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import ive

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.agents.base import Context
from zsbfm.evaluate import context_episode
from zsbfm.nets.encoder import ContextEncoder
from zsbfm.ops.vmf import householder_to, sample_vmf, sample_vmf_cosine
from tests.conftest import jit_optimised


def mean_cosine(d, kappa):
    """A_d(kappa) = I_{d/2}(kappa) / I_{d/2-1}(kappa) (scaled Bessel functions: same ratio)."""
    return ive(d / 2, kappa) / ive(d / 2 - 1, kappa)


@pytest.mark.parametrize("d,kappa", [(3, 1.0), (3, 10.0), (10, 5.0), (20, 50.0), (100, 50.0), (100, 200.0)])
def test_vmf_cosine_moments_match_closed_form(d, kappa):
    n = 40_000
    w = np.asarray(sample_vmf_cosine(jax.random.PRNGKey(d + int(kappa)), n, d, kappa), np.float64)
    A = mean_cosine(d, kappa)
    second = 1.0 - (d - 1) * A / kappa          # E[w^2]
    sd = np.sqrt(max(second - A**2, 1e-12))
    assert abs(w.mean() - A) < 5 * sd / np.sqrt(n), (w.mean(), A)
    # The spread (what skipping Wood's rejection step gets wrong): E[w^2] within 5%.
    assert abs(np.var(w) - (second - A**2)) < 0.05 * (second - A**2), (np.var(w), second - A**2)
    assert w.min() >= -1.0 and w.max() <= 1.0


def test_vmf_samples_are_unit_and_centred_on_mu():
    d, kappa, n = 50, 50.0, 20_000
    mu = jax.random.normal(jax.random.PRNGKey(0), (d,))
    mus = jnp.broadcast_to(mu * 3.0, (n, d))  # any scale: the direction is h / |h|
    x = np.asarray(sample_vmf(jax.random.PRNGKey(1), mus, kappa))
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-5)
    u = np.asarray(mu / jnp.linalg.norm(mu))
    assert abs((x @ u).mean() - mean_cosine(d, kappa)) < 0.01
    # the mean direction of the samples is mu
    m = x.mean(0)
    assert m @ u / np.linalg.norm(m) > 0.999


def test_householder_maps_e1_to_mu_and_is_orthogonal():
    d = 7
    mu = jax.random.normal(jax.random.PRNGKey(2), (d,))
    mu = mu / jnp.linalg.norm(mu)
    H = np.asarray(jax.vmap(lambda e: householder_to(mu, e))(jnp.eye(d))).T  # columns H e_i
    np.testing.assert_allclose(H[:, 0], np.asarray(mu), atol=1e-6)
    np.testing.assert_allclose(H @ H.T, np.eye(d), atol=1e-5)
    e1 = jnp.eye(d)[0]
    np.testing.assert_allclose(np.asarray(householder_to(e1, mu)), np.asarray(mu), atol=1e-7)


def test_vmf_sampler_is_jittable_and_keys_matter():
    f = jax.jit(lambda k: sample_vmf(k, jnp.ones((8, 5)), 10.0))
    a, b = f(jax.random.PRNGKey(0)), f(jax.random.PRNGKey(1))
    assert not np.allclose(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(a), np.asarray(f(jax.random.PRNGKey(0))))


@pytest.fixture(scope="module")
def encoder():
    net = ContextEncoder(h_dim=6, embed=16, heads=2, layers=2, mlp=32)
    tokens = jax.random.normal(jax.random.PRNGKey(0), (3, 12, 9))
    params = net.init(jax.random.PRNGKey(1), tokens, jnp.ones((3, 12), bool))
    return net, params, tokens


def test_encoder_is_permutation_invariant(encoder):
    net, params, tokens = encoder
    mask = jnp.ones(tokens.shape[:2], bool)
    mu, ls = net.apply(params, tokens, mask)
    perm = jax.random.permutation(jax.random.PRNGKey(3), 12)
    mu_p, ls_p = net.apply(params, tokens[:, perm], mask)
    np.testing.assert_allclose(np.asarray(mu), np.asarray(mu_p), atol=1e-5)
    np.testing.assert_allclose(np.asarray(ls), np.asarray(ls_p), atol=1e-5)
    assert mu.dtype == jnp.float32


def test_encoder_ignores_padding(encoder):
    net, params, tokens = encoder
    mu, _ = net.apply(params, tokens, jnp.ones(tokens.shape[:2], bool))
    junk = 100.0 * jax.random.normal(jax.random.PRNGKey(4), (3, 5, 9))
    padded = jnp.concatenate([tokens, junk], 1)
    mask = jnp.concatenate([jnp.ones((3, 12), bool), jnp.zeros((3, 5), bool)], 1)
    mu_pad, _ = net.apply(params, padded, mask)
    np.testing.assert_allclose(np.asarray(mu), np.asarray(mu_pad), atol=1e-5)
    # and the padding must not be trivially ignored because the output is constant
    mu_other, _ = net.apply(params, tokens[:, :6], jnp.ones((3, 6), bool))
    assert not np.allclose(np.asarray(mu), np.asarray(mu_other), atol=1e-3)


@pytest.mark.parametrize("pool, pool_width", [("mean", 0), ("max", 0), ("max", 40)])
def test_pooling_is_permutation_invariant_and_ignores_padding(pool, pool_width):
    net = ContextEncoder(h_dim=6, embed=16, heads=2, layers=2, mlp=32, pool=pool, pool_width=pool_width)
    tokens = jax.random.normal(jax.random.PRNGKey(0), (3, 12, 9))
    params = net.init(jax.random.PRNGKey(1), tokens, jnp.ones((3, 12), bool))
    mu, _ = net.apply(params, tokens, jnp.ones((3, 12), bool))
    perm = jax.random.permutation(jax.random.PRNGKey(3), 12)
    np.testing.assert_allclose(np.asarray(net.apply(params, tokens[:, perm], jnp.ones((3, 12), bool))[0]),
                               np.asarray(mu), atol=1e-5)
    junk = 100.0 * jax.random.normal(jax.random.PRNGKey(4), (3, 5, 9))
    mask = jnp.concatenate([jnp.ones((3, 12), bool), jnp.zeros((3, 5), bool)], 1)
    mu_pad, _ = net.apply(params, jnp.concatenate([tokens, junk], 1), mask)
    np.testing.assert_allclose(np.asarray(mu_pad), np.asarray(mu), atol=1e-5)


def test_max_pooling_is_a_max_over_every_token_of_every_episode():
    """With no attention (layers=0) each token's features are its own, so the max over tokens
    then over episodes is one max over all K * N tokens, and a repeated token changes
    nothing; a mean-pooled encoder moves when a token is repeated."""
    tokens = jax.random.normal(jax.random.PRNGKey(0), (2, 4, 7, 9))              # [B, K, N, in]
    flat = tokens.reshape(2, 28, 9)
    nets = {p: ContextEncoder(h_dim=6, embed=16, heads=2, layers=0, mlp=32, pool=p) for p in ("max", "mean")}
    params = nets["max"].init(jax.random.PRNGKey(1), flat, jnp.ones((2, 28), bool))
    by_episode, _ = nets["max"].apply(params, tokens, jnp.ones((2, 4, 7), bool), episode_axis=True)
    at_once, _ = nets["max"].apply(params, flat, jnp.ones((2, 28), bool))
    np.testing.assert_allclose(np.asarray(by_episode), np.asarray(at_once), atol=1e-5)
    repeated = jnp.concatenate([flat, flat[:, :1]], 1)
    for pool, moves in (("max", False), ("mean", True)):
        a = nets[pool].apply(params, flat, jnp.ones((2, 28), bool))[0]
        b = nets[pool].apply(params, repeated, jnp.ones((2, 29), bool))[0]
        assert np.allclose(np.asarray(a), np.asarray(b), atol=1e-5) != moves, pool


def embedded_by_hand(p, tokens):
    """LN(E tok): the token embedding and LayerNorm of an encoder with no blocks, from its parameters."""
    x = tokens @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"]
    x = (x - x.mean(-1, keepdims=True)) / jnp.sqrt(x.var(-1, keepdims=True) + 1e-6)
    return x * p["LayerNorm_0"]["scale"] + p["LayerNorm_0"]["bias"]


def test_pool_width_maps_each_token_to_that_many_channels_before_the_max():
    """pool_width = P: mu = W_mu max_t(W_P LN(E tok_t) + b_P) + b_mu, computed here by hand
    from the parameters (layers=0: no attention), P independent channels."""
    tokens = jax.random.normal(jax.random.PRNGKey(0), (2, 7, 9))
    net = ContextEncoder(h_dim=6, embed=16, heads=2, layers=0, mlp=32, pool="max", pool_width=40)
    params = net.init(jax.random.PRNGKey(1), tokens, jnp.ones((2, 7), bool))
    p = params["params"]
    assert p["pool_in"]["kernel"].shape == (16, 40) and p["mu"]["kernel"].shape == (40, 6)
    x = embedded_by_hand(p, tokens)
    pooled = jnp.max(x @ p["pool_in"]["kernel"] + p["pool_in"]["bias"], axis=1)
    mu = pooled @ p["mu"]["kernel"] + p["mu"]["bias"]
    np.testing.assert_allclose(np.asarray(net.apply(params, tokens, jnp.ones((2, 7), bool))[0]),
                               np.asarray(mu), rtol=1e-4, atol=1e-4)


def test_cell_pool_is_softmax_attention_of_one_query_per_cell_over_the_tokens_and_a_null_token():
    """pool="cells", one head, no blocks: feature c of the pooled vector is
    W_o sum_j softmax_j(<W_q q_c + b_q, W_k x_j + b_k> / sqrt(E)) (W_v x_j + b_v) + b_o, j over
    the unmasked tokens x_j = LN(E tok_j) and the null token n, computed here by hand; a
    context with no unmasked token reads n alone, whatever its tokens. The second context's
    last 3 tokens are masked: padding is left out exactly (order invariance: the next test)."""
    E, C, P = 16, 5, 3
    tokens = jax.random.normal(jax.random.PRNGKey(0), (2, 7, 9))
    mask = jnp.asarray([[True] * 7, [True] * 4 + [False] * 3])
    net = ContextEncoder(h_dim=6, embed=E, heads=1, layers=0, mlp=32, pool="cells", pool_width=P, cells=C)
    params = net.init(jax.random.PRNGKey(1), tokens, mask)
    p = params["params"]
    cp, att = p["CellPool_0"], p["CellPool_0"]["MultiHeadDotProductAttention_0"]
    x = embedded_by_hand(p, tokens)
    proj = lambda name, v: v @ att[name]["kernel"][:, 0] + att[name]["bias"][0]
    expected = []
    for i in range(2):
        kv = np.concatenate([np.asarray(x[i])[np.asarray(mask[i])], np.asarray(cp["null"])], 0)
        logits = np.asarray(proj("query", cp["queries"]) @ proj("key", kv).T) / np.sqrt(E)   # [C, M + 1]
        w = np.exp(logits - logits.max(1, keepdims=True))
        w /= w.sum(1, keepdims=True)
        y = (w @ np.asarray(proj("value", kv))) @ np.asarray(att["out"]["kernel"][0]) + np.asarray(att["out"]["bias"])
        y = y @ np.asarray(cp["cell_out"]["kernel"]) + np.asarray(cp["cell_out"]["bias"])      # [C, P]
        expected.append(y.reshape(-1) @ np.asarray(p["mu"]["kernel"]) + np.asarray(p["mu"]["bias"]))
    np.testing.assert_allclose(np.asarray(net.apply(params, tokens, mask)[0]), np.stack(expected),
                               rtol=1e-4, atol=1e-4)
    empty = jnp.zeros((2, 7), bool)
    a, b = (np.asarray(net.apply(params, t, empty)[0]) for t in (tokens, -3.0 * tokens))
    assert np.isfinite(a).all()
    np.testing.assert_allclose(a, b, atol=1e-6)
    np.testing.assert_allclose(a[0], a[1], atol=1e-6)


def test_cell_pooling_reads_every_episode_of_a_context_at_once():
    """pool="cells" with an episode axis attends over all K * N tokens in one pool: with no
    blocks (no attention within an episode) it equals the flattened context; with blocks it is
    invariant to the episodes' order and not the first episode's alone."""
    tokens = jax.random.normal(jax.random.PRNGKey(0), (2, 3, 7, 9))              # [B, K, N, in]
    mask = jnp.ones((2, 3, 7), bool).at[:, 2, 4:].set(False)
    for layers in (0, 2):
        net = ContextEncoder(h_dim=6, embed=16, heads=2, layers=layers, mlp=32, pool="cells", cells=4)
        params = net.init(jax.random.PRNGKey(1), tokens, mask, True)
        mu = np.asarray(net.apply(params, tokens, mask, True)[0])
        if layers == 0:
            flat = np.asarray(net.apply(params, tokens.reshape(2, 21, 9), mask.reshape(2, 21))[0])
            np.testing.assert_allclose(mu, flat, atol=1e-5)
        reordered = net.apply(params, tokens[:, ::-1], mask[:, ::-1], True)[0]
        np.testing.assert_allclose(np.asarray(reordered), mu, atol=1e-5)
        first = np.asarray(net.apply(params, tokens[:, :1], mask[:, :1], True)[0])
        assert not np.allclose(first, mu, atol=1e-3)


def test_evidence_pool_sums_each_tokens_wall_and_free_evidence_by_its_predicted_cell():
    """pool="evidence", no blocks: with p_j = softmax(W_a x_j + b_a) over C cells and
    s_j = sigmoid(w_e x_j + b_e), the pooled features are log(1 + sum_j m_j p_jc s_j) then
    log(1 + sum_j m_j p_jc (1 - s_j)) per cell c, computed here by hand over the unmasked tokens
    x_j = LN(E tok_j); the sown logits are those of every token; K episodes pool as one set."""
    C = 5
    tokens = jax.random.normal(jax.random.PRNGKey(0), (2, 7, 9))
    mask = jnp.asarray([[True] * 7, [True] * 4 + [False] * 3])
    net = ContextEncoder(h_dim=6, embed=16, heads=2, layers=0, mlp=32, pool="evidence", cells=C)
    params = net.init(jax.random.PRNGKey(1), tokens, mask)
    p = params["params"]
    ev = p["evidence"]
    x = np.asarray(embedded_by_hand(p, tokens), np.float64)
    logits = x @ np.asarray(ev["cell_head"]["kernel"]) + np.asarray(ev["cell_head"]["bias"])   # [2, 7, C]
    wall = x @ np.asarray(ev["wall_head"]["kernel"])[:, 0] + np.asarray(ev["wall_head"]["bias"])[0]
    prob = np.exp(logits - logits.max(-1, keepdims=True))
    prob /= prob.sum(-1, keepdims=True)
    s = 1.0 / (1.0 + np.exp(-wall))
    expected, counts = [], []
    for i in range(2):
        m = np.asarray(mask[i])
        n_wall, n_free = ((prob[i][m] * v[m, None]).sum(0) for v in (s[i], 1.0 - s[i]))
        feat = np.concatenate([np.log1p(n_wall), np.log1p(n_free)])
        expected.append(feat @ np.asarray(p["mu"]["kernel"]) + np.asarray(p["mu"]["bias"]))
        counts.append((n_wall, n_free))
    (mu, _), sown = net.apply(params, tokens, mask, mutable=["intermediates"])
    np.testing.assert_allclose(np.asarray(mu), np.stack(expected), rtol=1e-4, atol=1e-4)
    for k, name in enumerate(("n_wall", "n_free")):
        np.testing.assert_allclose(np.asarray(sown["intermediates"]["evidence"][name][0]),
                                   np.stack([c[k] for c in counts]), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(sown["intermediates"]["evidence"]["cell_logits"][0]), logits,
                               rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(sown["intermediates"]["evidence"]["wall_logit"][0]), wall,
                               rtol=1e-4, atol=1e-4)
    split = net.apply(params, tokens.reshape(2, 7, 1, 9), mask.reshape(2, 7, 1), True)[0]
    np.testing.assert_allclose(np.asarray(split), np.asarray(mu), atol=1e-5)   # 7 one-token episodes


def test_the_evidence_loss_is_cross_entropy_to_the_pointed_cell_plus_bce_to_its_wall_label():
    """enc_pool="evidence": the encoder loss's enc_cell_ce and enc_wall_bce equal, computed
    here in numpy, the mean over tokens of -log softmax(cell_logits)[q] with q = the cell the
    move points at ((x + dx, y + dy) of the token's s and a), and of the binary cross-entropy
    of the wall logit with the layout's wall at q; with K = 2 episodes per context."""
    from zsbfm.data import collect
    from tests.test_envs import DELTAS

    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=4, h_from="context",
                              context_loss="bce", enc_pool="evidence", context_episodes=2,
                              enc_embed=8, enc_mlp=8, enc_layers=1, pred_hidden=(8,))
    env = zsbfm.make_env("fourrooms", n_train=3)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 4))(jax.random.PRNGKey(0))
    enc = jax.jit(agent.init)(jax.random.PRNGKey(1)).params.enc
    ep = jnp.arange(0, 12, 2)
    window = tuple(x[:, :, :10] for x in agent.sample_contexts(jax.random.PRNGKey(3), ds, ep))   # [6, 2, 10, ...]
    _, (metrics, _) = jax.jit(agent.encoder_loss)(enc, window, window, jax.random.PRNGKey(2), ds.context_id[ep])
    _, sown = agent.encode(enc, *window, episodes=True, sown=True)
    logits = np.asarray(sown["intermediates"]["evidence"]["cell_logits"][0], np.float64)     # [6, 20, 121]
    wall = np.asarray(sown["intermediates"]["evidence"]["wall_logit"][0], np.float64)
    walls = np.asarray(env.contexts("train").walls)
    obs, act = np.asarray(window[0]).astype(int).reshape(6, 20, 2), np.asarray(window[1]).reshape(6, 20)
    ce, bce = [], []
    for i, layout in enumerate(np.asarray(ds.context_id[ep])):
        for j in range(20):
            (x, y), (dx, dy) = obs[i, j], DELTAS[int(act[i, j])]
            q, k = (y + dy) * env.size + (x + dx), float(walls[layout, y + dy, x + dx])
            ce.append(-(logits[i, j, q] - np.log(np.exp(logits[i, j]).sum())))
            p = 1.0 / (1.0 + np.exp(-wall[i, j]))
            bce.append(-k * np.log(p) - (1 - k) * np.log(1 - p))
    np.testing.assert_allclose(float(metrics["enc_cell_ce"]), np.mean(ce), rtol=1e-4)
    np.testing.assert_allclose(float(metrics["enc_wall_bce"]), np.mean(bce), rtol=1e-4)


def test_evidence_read_takes_the_seen_cells_wall_fraction_and_the_head_elsewhere():
    """context_read="evidence": n^wall / (n^wall + n^free) where n^wall + n^free >= 1/2, the
    head's value where the context holds less evidence of the cell."""
    from zsbfm.agents.belief import BeliefFBAgent

    n_wall = jnp.asarray([[2.0, 0.0, 0.3, 0.1, 0.0]])
    n_free = jnp.asarray([[0.0, 3.0, 0.3, 0.2, 0.0]])
    head = jnp.asarray([[0.2, 0.9, 0.7, 0.4, 0.6]])
    got = BeliefFBAgent.evidence_read(n_wall, n_free, head)
    np.testing.assert_allclose(np.asarray(got), [[1.0, 0.0, 0.5, 0.4, 0.6]], rtol=1e-6)


def test_context_read_evidence_puts_the_pools_counts_into_the_heads_map():
    """context_h with context_read="evidence": per interior cell (the wall map's order, walls[1:-1,
    1:-1] flattened), the sown counts' wall fraction where they sum to >= 1/2, sigmoid(c(mu))
    elsewhere, computed here in numpy; the h table (context_len = episode_len, h_train_true off)
    holds the same h of each episode. The cell head's kernel is scaled up so that each token
    points at one cell, as a trained one does, and some cells are seen."""
    from zsbfm.data import collect

    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=2, h_from="context",
                              context_loss="bce", enc_pool="evidence", context_read="evidence",
                              enc_embed=8, enc_mlp=8, enc_layers=1, pred_hidden=(8,))
    env = zsbfm.make_env("fourrooms", n_train=3)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 2))(jax.random.PRNGKey(0))
    state = jax.jit(agent.init)(jax.random.PRNGKey(1))
    enc = state.params.enc
    cell_head = enc["encoder"]["params"]["evidence"]["cell_head"]
    enc["encoder"]["params"]["evidence"]["cell_head"] = dict(cell_head, kernel=cell_head["kernel"] * 40.0)
    state = state.replace(params=state.params.replace(enc=enc))

    h = jax.jit(jax.vmap(lambda o, a: agent.context_h(state.params, Context(obs=o, action=a))))(ds.obs, ds.action)
    (mu, _), sown = agent.encode(enc, ds.obs[:, :-1], ds.action, ds.obs[:, 1:], sown=True)
    n_wall, n_free = (np.asarray(sown["intermediates"]["evidence"][k][0], np.float64) for k in ("n_wall", "n_free"))
    interior = lambda v: v.reshape(-1, env.size, env.size)[:, 1:-1, 1:-1].reshape(v.shape[0], -1)   # noqa: E731
    n_wall, n_free = interior(n_wall), interior(n_free)
    head = 1.0 / (1.0 + np.exp(-np.asarray(agent.context_head.apply(enc["context_head"], mu), np.float64)))
    seen = n_wall + n_free >= 0.5
    expected = np.where(seen, n_wall / np.maximum(n_wall + n_free, 0.5), head)
    assert 0 < seen.sum() < seen.size
    np.testing.assert_allclose(np.asarray(h), expected, rtol=1e-4, atol=1e-5)
    assert not np.allclose(np.asarray(h)[seen], head[seen], atol=1e-2)   # the head alone reads otherwise

    state = jax.jit(agent.build_h_table)(state, ds, jax.random.PRNGKey(4))
    np.testing.assert_allclose(np.asarray(state.h_table[:, 0]), expected, rtol=1e-4, atol=1e-5)


def test_discrete_actions_enter_the_encoder_one_hot():
    cfg = zsbfm.Config.preset("fourrooms", "bfb")
    agent = make_agent(cfg, zsbfm.make_env("fourrooms"))
    tok = agent.tokens(jnp.zeros((5, 2)), jnp.array([0, 1, 2, 3, 1]), jnp.zeros((5, 2)))
    k = agent.obs_features(jnp.zeros((1, 2))).shape[-1]  # tokens: [phi(s), a, phi(s'), s' - s]
    np.testing.assert_array_equal(np.asarray(tok[:, k:k + 4]), np.eye(4)[[0, 1, 2, 3, 1]])


def test_contrastive_loss_matches_a_loop_and_rewards_grouping_by_layout():
    """enc_contrast's InfoNCE against the formula written out with Python loops; it is
    lower when h groups windows by layout than when h mixes the layouts."""
    from zsbfm.agents.belief import BeliefFBAgent

    rng = np.random.default_rng(0)
    mu, mu_t = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    ctx = np.array([0, 1, 0, 2, 1, 0])
    expect = 0.0
    for i in range(6):
        e = [np.exp(-np.sum((mu[i] - mu_t[j]) ** 2)) for j in range(6)]
        expect -= np.log(sum(e[j] for j in range(6) if ctx[j] == ctx[i]) / sum(e)) / 6
    got = BeliefFBAgent.contrastive_loss(jnp.asarray(mu), jnp.asarray(mu_t), jnp.asarray(ctx))
    np.testing.assert_allclose(float(got), expect, rtol=1e-5)

    centres = 3.0 * np.eye(3)[ctx]                       # one point per layout, far apart
    grouped = BeliefFBAgent.contrastive_loss(*map(jnp.asarray, (centres, centres, ctx)))
    mixed = BeliefFBAgent.contrastive_loss(*map(jnp.asarray, (centres, centres[::-1], ctx)))
    assert float(grouped) < 0.01 < float(mixed)


def test_enc_contrast_must_be_non_negative():
    with pytest.raises(ValueError, match="enc_contrast"):
        zsbfm.Config.preset("antwind", "bfb", enc_contrast=-1.0)


def test_rfb_requires_h_dim_equal_d():
    with pytest.raises(ValueError, match="Config.h_dim=8"):
        zsbfm.Config.preset("fourrooms", "rfb", d=16, h_dim=8)


@pytest.mark.parametrize("bad", [dict(algo="rfb"), dict(algo="bfb", encoder_mode="joint"),
                                 dict(algo="bfb", h_noise=True)])
def test_h_from_context_is_belief_fbs_staged_mean_only(bad):
    bad = dict(bad)
    algo = bad.pop("algo")
    with pytest.raises(ValueError, match="Config.h_from='context'"):
        zsbfm.Config.preset("fourrooms", algo, h_from="context", **bad)


@pytest.mark.parametrize("fields, message", [
    (dict(h_from="walls"), "Config.h_from='walls'"),
    (dict(h_train_true=True), "Config.h_train_true=True"),
    (dict(h_from="context", enc_context_coef=0.0), "Config.enc_context_coef=0.0"),
    (dict(h_from="context", context_loss="huber"), "Config.context_loss='huber'"),
    (dict(h_from="context", context_head_hidden=(64, 0)), r"Config.context_head_hidden=\(64, 0\)"),
    (dict(context_loss="bce"), "Config.h_from='mu'"),
    (dict(context_head_hidden=(64,)), "Config.h_from='mu'"),
    (dict(env="antwind", h_from="context", context_loss="bce"), "Config.context_loss='bce'"),
    (dict(enc_pool="sum"), "Config.enc_pool='sum'"),
    (dict(enc_pool_width=-1), "Config.enc_pool_width=-1"),
    (dict(enc_pool_width=64), "Config.enc_pool_width=64"),
    (dict(env="antwind", enc_pool="cells"), "Config.enc_pool='cells' .*cell map"),
    (dict(env="pointmass", enc_pool="evidence"), "Config.enc_pool='evidence' .*points at"),
    (dict(enc_pool="evidence", enc_pool_width=4), "Config.enc_pool_width=4 .*evidence"),
    (dict(h_from="context", enc_pool="evidence", context_read="map"), "Config.context_read='map'"),
    (dict(h_from="context", context_read="evidence"), "Config.context_read='evidence' .*enc_pool='mean'"),
    (dict(enc_pool="evidence", context_read="evidence"), "Config.context_read='evidence' .*h_from='mu'"),
])
def test_h_from_settings_are_checked(fields, message):
    fields = dict(fields)
    env = fields.pop("env", "fourrooms")
    with pytest.raises(ValueError, match=message):
        zsbfm.Config.preset(env, "bfb", **fields)


@pytest.mark.parametrize("fields, message", [
    (dict(algo="bfb", context_episodes=0), "Config.context_episodes=0"),
    (dict(algo="bfb", context_episodes=3, episodes_per_layout=2), "Config.context_episodes=3"),
    (dict(algo="fb", context_episodes=2), "Config.context_episodes=2"),
])
def test_context_episodes_is_checked(fields, message):
    fields = dict(fields)
    algo = fields.pop("algo")
    with pytest.raises(ValueError, match=message):
        zsbfm.Config.preset("fourrooms", algo, **fields)


def test_a_multi_episode_context_draws_distinct_episodes_of_one_layout():
    per, K = 5, 4
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=per, context_episodes=K)
    agent = make_agent(cfg, zsbfm.make_env("fourrooms", n_train=3))
    episode = jnp.arange(3 * per)
    eps = np.asarray(agent.context_episodes_of(jax.random.PRNGKey(0), episode))
    assert eps.shape == (3 * per, K)
    np.testing.assert_array_equal(eps[:, 0], np.arange(3 * per))             # the episode itself first
    np.testing.assert_array_equal(eps // per, np.repeat(np.arange(3 * per) // per, K).reshape(-1, K))
    assert all(len(set(row)) == K for row in eps.tolist())                    # without replacement
    again = np.asarray(agent.context_episodes_of(jax.random.PRNGKey(1), episode))
    assert (again != eps).any()                                               # the key matters


@pytest.mark.slow  # ~30 s of eager encoder calls; the cells and evidence pools' episode axis stay in the default run
def test_a_k_episode_context_is_max_pooled_over_its_episodes():
    """h of a K-episode context: invariant to the order of the episodes and of the
    transitions within one, unchanged when an episode is repeated (a max, not a mean), and
    not that of its first episode alone; the test-time context holds K independent episodes."""
    K, T = 3, 6
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=2, episodes_per_layout=4, context_episodes=K)
    env = zsbfm.make_env("fourrooms", n_train=2)
    agent = make_agent(cfg, env)
    params = agent.eval_params(agent.init(jax.random.PRNGKey(0)))
    layout = jax.tree_util.tree_map(lambda x: x[0], env.contexts("train"))
    context = context_episode(env, jax.random.PRNGKey(2), layout, T, K)
    assert context.obs.shape == (K, T + 1, env.obs_dim) and context.action.shape == (K, T)
    assert len({tuple(np.asarray(context.obs[k]).ravel()) for k in range(K)}) == K  # independent episodes
    h = lambda obs, action: np.asarray(agent.context_h(params, Context(obs=obs, action=action, layout=layout)))
    h0 = h(context.obs, context.action)
    np.testing.assert_allclose(h(context.obs[::-1], context.action[::-1]), h0, atol=1e-5)
    # transitions (s, a, s') permuted within episode 1: the same set of transitions
    perm = jax.random.permutation(jax.random.PRNGKey(3), T)
    tok = agent.tokens(context.obs[:, :-1], context.action, context.obs[:, 1:])
    mu = lambda t: np.asarray(agent.encoder_net.apply(params.enc["encoder"], t, jnp.ones(t.shape[:-1], bool), True)[0])
    np.testing.assert_allclose(mu(tok.at[1].set(tok[1, perm])), mu(tok), atol=1e-5)
    # repeating episode 0 in place of episode 2 adds nothing to what episodes 0 and 1 show
    two = mu(tok[:2])
    np.testing.assert_allclose(mu(tok.at[2].set(tok[0])), two, atol=1e-5)
    assert np.abs(mu(tok) - two).max() > 1e-4 and np.abs(h(context.obs[:1], context.action[:1]) - h0).max() > 1e-4
    # a one-episode context with the K axis is the paper's one-episode h
    np.testing.assert_allclose(h(context.obs[:1], context.action[:1]), h(context.obs[0], context.action[0]), atol=1e-5)


def test_h_train_true_trains_f_on_each_transitions_own_layout_walls():
    from zsbfm.data import collect
    from zsbfm.data.samplers import Transitions

    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=2, h_from="context",
                              h_train_true=True)
    env = zsbfm.make_env("fourrooms", n_train=3)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 2))(jax.random.PRNGKey(0))
    episode = jnp.array([5, 0, 3, 2])
    batch = Transitions(obs=ds.obs[episode, 0], action=ds.action[episode, 0], next_obs=ds.obs[episode, 1],
                        episode=episode, t=jnp.zeros(4, jnp.int32))
    h = agent.train_context(None, ds, batch, jax.random.PRNGKey(1))   # reads no state: the table is unused
    walls = np.asarray(env.contexts("train").walls)[np.asarray(ds.context_id)[np.asarray(episode)]]
    np.testing.assert_array_equal(np.asarray(h), walls[:, 1:-1, 1:-1].reshape(4, -1).astype(np.float32))


def test_h_train_mask_hides_features_behind_the_mean_map_at_its_rate():
    """h_train_mask=p: each feature is the true wall or, with probability p, the train layouts'
    mean map; fresh keys hide other features."""
    from zsbfm.data import collect
    from zsbfm.data.samplers import Transitions

    p = 0.3
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=2, h_from="context",
                              h_train_true=True, h_train_mask=p)
    env = zsbfm.make_env("fourrooms", n_train=3)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 2))(jax.random.PRNGKey(0))
    episode = jnp.tile(jnp.arange(6), 200)
    batch = Transitions(obs=ds.obs[episode, 0], action=ds.action[episode, 0], next_obs=ds.obs[episode, 1],
                        episode=episode, t=jnp.zeros_like(episode))
    h = np.asarray(agent.train_context(None, ds, batch, jax.random.PRNGKey(1)))
    walls = np.asarray(env.contexts("train").walls)[:, 1:-1, 1:-1].reshape(3, -1).astype(np.float32)
    true, mean = walls[np.asarray(ds.context_id)[np.asarray(episode)]], walls.mean(0)
    assert np.all((h == true) | (h == mean))
    varying = true != mean  # where hiding shows
    rate = ((h != true) & varying).sum() / varying.sum()
    assert varying.sum() > 1000 and abs(rate - p) < 5 * np.sqrt(p * (1 - p) / varying.sum()), rate
    h2 = np.asarray(agent.train_context(None, ds, batch, jax.random.PRNGKey(2)))
    assert np.any(h2 != h)
    with pytest.raises(ValueError, match="Config.h_train_mask=0.3 .*h_train_true=True"):
        zsbfm.Config.preset("fourrooms", "bfb", h_from="context", h_train_mask=p)
    with pytest.raises(ValueError, match=r"Config.h_train_mask=1.0 .*\[0, 1\)"):
        zsbfm.Config.preset("fourrooms", "bfb", h_from="context", h_train_true=True, h_train_mask=1.0)


def test_context_target_revealed_is_the_map_where_the_window_shows_it_and_the_mean_elsewhere():
    """context_target="revealed": the head's target is the true wall on the cells the window
    entered or bumped into (env.revealed_features) and the train layouts' mean map elsewhere;
    "map" is the true map; K-episode windows reveal the union of their episodes."""
    from zsbfm.data import collect

    env = zsbfm.make_env("fourrooms", n_train=3)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 4))(jax.random.PRNGKey(0))
    walls = np.asarray(env.contexts("train").walls)[:, 1:-1, 1:-1].reshape(3, -1).astype(np.float32)
    ctx = np.asarray(ds.context_id)
    window = (ds.obs[:, :-1], ds.action, ds.obs[:, 1:])
    seen = np.asarray(jax.vmap(env.revealed_features)(*window))
    targets = {}
    for target in ("map", "revealed"):
        cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=4,
                                  h_from="context", context_target=target)
        targets[target] = np.asarray(make_agent(cfg, env).context_target(window, jnp.asarray(ctx)))
    np.testing.assert_array_equal(targets["map"], walls[ctx])
    np.testing.assert_array_equal(targets["revealed"], np.where(seen, walls[ctx], walls.mean(0)))
    assert (targets["revealed"] != targets["map"]).any()
    # two episodes of one layout as one K = 2 window: the union of what each showed
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=4, h_from="context",
                              context_target="revealed", context_episodes=2)
    pair = tuple(x[None, :2] for x in window)                    # episodes 0 and 1: layout 0
    got = np.asarray(make_agent(cfg, env).context_target(pair, jnp.asarray([ctx[0]])))[0]
    np.testing.assert_array_equal(got, np.where(seen[0] | seen[1], walls[0], walls.mean(0)))
    with pytest.raises(ValueError, match="Config.context_target='revealed' .*h_from='context'"):
        zsbfm.Config.preset("fourrooms", "bfb", context_target="revealed")
    with pytest.raises(ValueError, match="Config.context_target='seen' .*one of"):
        zsbfm.Config.preset("fourrooms", "bfb", h_from="context", context_target="seen")
    with pytest.raises(ValueError, match="Config.context_target='revealed' .*env='antwind'"):
        zsbfm.Config.preset("antwind", "bfb", h_from="context", context_target="revealed")


# ~30 s each, in `make test-all`; the default run keeps the head's loss (the bce test below) and
# F's training h (test_h_train_true_trains_f_on_each_transitions_own_layout_walls)
@pytest.mark.parametrize("hidden, loss", [pytest.param((), "mse", marks=pytest.mark.slow),
                                          pytest.param((64,), "bce", marks=pytest.mark.slow)])
def test_h_from_context_predicts_the_wall_map_and_is_what_f_reads(hidden, loss):
    """h_from="context": a short pre-training makes c(mu) of fresh episodes predict their
    layout's wall map better than the best constant (the train layouts' mean map), and the h
    table F reads holds c(mu) of every episode: 81 numbers, the walls oracle's h (with
    context_loss="bce", sigmoid of the head's logits: probabilities of a wall)."""
    from zsbfm.data import collect

    n = 4
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=n, episodes_per_layout=50, h_from="context",
                              context_head_hidden=hidden, context_loss=loss,
                              enc_steps=400, steps=1400, chunk_steps=100, enc_embed=32, enc_mlp=64,
                              pred_hidden=(64, 64), d=16, f_pre_hidden=(8,), f_pre_out=8, f_hidden=(8,),
                              b_hidden=(8,), batch_size=8)
    env = zsbfm.make_env("fourrooms", n_train=n)
    agent = make_agent(cfg, env)
    assert (agent.h_dim, agent.mu_dim) == (81, 16)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 50))(jax.random.PRNGKey(0))
    state = jax.jit(agent.init)(jax.random.PRNGKey(1))
    pre = jit_optimised(lambda s, k: jax.lax.scan(lambda s, k: agent.pretrain_step(s, ds, k), s,
                                                  jax.random.split(k, cfg.enc_steps)))
    state, metrics = pre(state, jax.random.PRNGKey(2))
    assert metrics["enc_ctx_mse"][-20:].mean() < 0.5 * metrics["enc_ctx_mse"][:20].mean()

    held_out = jax.jit(lambda k: collect(env, k, env.contexts("train"), 10))(jax.random.PRNGKey(3))
    h = jax.jit(jax.vmap(lambda o, a: agent.context_h(state.params, Context(obs=o, action=a))))(
        held_out.obs, held_out.action)
    walls = np.asarray(jax.vmap(env.context_features)(env.contexts("train")))[np.asarray(held_out.context_id)]
    best_constant = np.asarray(agent.layout_features).mean(0)
    assert np.mean((np.asarray(h) - walls) ** 2) < 0.6 * np.mean((best_constant - walls) ** 2)

    state = jax.jit(agent.build_h_table)(state, ds, jax.random.PRNGKey(4))
    mu = jax.jit(lambda enc: agent.encode(enc, ds.obs[:, :-1], ds.action, ds.obs[:, 1:])[0])(state.params.enc)
    out = np.asarray(agent.context_head.apply(state.params.enc["context_head"], mu), np.float64)
    expected = 1.0 / (1.0 + np.exp(-out)) if loss == "bce" else out
    if loss == "bce":
        assert np.all((np.asarray(h) > 0) & (np.asarray(h) < 1))
    np.testing.assert_allclose(np.asarray(state.h_table[:, 0]), expected, rtol=1e-4, atol=1e-4)


def test_gridworld_cell_tokens_name_the_cell_the_wall_map_indexes():
    """enc_cell_tokens on a gridworld: the token's last n_cells entries are the one-hot of s's
    cell, and that index reads the same cell of the flattened wall map as walls[y, x]."""
    env = zsbfm.make_env("fourrooms", n_train=2)
    agent = make_agent(zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=2, enc_cell_tokens=True), env)
    walls = np.asarray(env.contexts("train").walls[0])
    xy = np.array([[x, y] for y in range(env.size) for x in range(env.size)], np.float32)   # every cell
    tok = np.asarray(agent.tokens(jnp.asarray(xy), jnp.zeros(len(xy), jnp.int32), jnp.asarray(xy)))
    idx = tok[:, -env.n_cells:].argmax(-1)
    np.testing.assert_array_equal(tok[:, -env.n_cells:].sum(-1), 1.0)
    assert sorted(idx) == list(range(env.n_cells))                     # one cell each, none shared
    np.testing.assert_array_equal(walls.reshape(-1)[idx], walls[xy[:, 1].astype(int), xy[:, 0].astype(int)])


def test_a_bce_context_head_is_an_mlp_of_logits_and_its_loss_is_the_binary_cross_entropy():
    """context_loss="bce": h = sigmoid(c(mu)) with c an MLP of context_head_hidden, and the
    encoder loss's enc_ctx_bce equals -k log p - (1 - k) log(1 - p) averaged, computed here in numpy."""
    from zsbfm.data import collect

    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=3, episodes_per_layout=2, h_from="context",
                              context_head_hidden=(16, 8), context_loss="bce", enc_contrast=0.0,
                              enc_embed=8, enc_mlp=8, enc_layers=1, pred_hidden=(8,))
    env = zsbfm.make_env("fourrooms", n_train=3)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 2))(jax.random.PRNGKey(0))
    enc = jax.jit(agent.init)(jax.random.PRNGKey(1)).params.enc
    kernels = [np.asarray(v["kernel"]).shape for v in enc["context_head"]["params"].values()]
    assert kernels == [(agent.mu_dim, 16), (16, 8), (8, 81)]
    window = (ds.obs[:, :10], ds.action[:, :10], ds.obs[:, 1:11])               # 10 transitions suffice
    _, (metrics, mu) = jax.jit(agent.encoder_loss)(enc, window, window, jax.random.PRNGKey(2), ds.context_id)
    logits = np.asarray(agent.context_head.apply(enc["context_head"], mu), np.float64)
    p = 1.0 / (1.0 + np.exp(-logits))
    k = np.asarray(agent.layout_features)[np.asarray(ds.context_id)]
    np.testing.assert_allclose(float(metrics["enc_ctx_bce"]), np.mean(-k * np.log(p) - (1 - k) * np.log(1 - p)),
                               rtol=1e-4)
    np.testing.assert_allclose(float(metrics["enc_ctx_mse"]), np.mean((p - k) ** 2), rtol=1e-4)
    np.testing.assert_allclose(np.asarray(agent.h_of_mu(enc, mu)), p, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("contrast, enc_steps, episodes", [
    pytest.param(1.0, 600, 50, marks=pytest.mark.slow),         # + the same-layout InfoNCE term: ~40 s
    pytest.param(0.0, 5000, 200, marks=pytest.mark.slow),       # the paper's loss alone: ~3 min
])
def test_short_encoder_pretraining_separates_fourrooms_layouts(contrast, enc_steps, episodes):
    """After a short pre-training, fresh episodes of the same layout sit closer in h than
    episodes of different layouts, and nearest neighbours find the layout."""
    from zsbfm.data import collect

    n_layouts = 4
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=n_layouts, episodes_per_layout=episodes,
                              enc_target="context", enc_contrast=contrast, enc_steps=enc_steps,
                              steps=enc_steps + 1000, chunk_steps=100,
                              enc_embed=32, enc_mlp=64, pred_hidden=(64, 64), d=16)
    env = zsbfm.make_env("fourrooms", n_train=n_layouts)
    agent = make_agent(cfg, env)
    episodes = jax.jit(lambda k, n: collect(env, k, env.contexts("train"), n), static_argnums=1)
    ds = episodes(jax.random.PRNGKey(0), cfg.episodes_per_layout)
    state = jax.jit(agent.init)(jax.random.PRNGKey(1))
    pre = jit_optimised(lambda s, k: jax.lax.scan(lambda s, k: agent.pretrain_step(s, ds, k), s,
                                                  jax.random.split(k, cfg.enc_steps)))
    state, metrics = pre(state, jax.random.PRNGKey(2))
    assert metrics["enc_mse"][-50:].mean() < metrics["enc_mse"][:50].mean()

    held_out = episodes(jax.random.PRNGKey(3), 25)
    mu, _ = jax.jit(agent.encode)(state.params.enc, held_out.obs[:, :-1], held_out.action, held_out.obs[:, 1:])
    h, ids = np.asarray(mu), np.asarray(held_out.context_id)
    D = np.linalg.norm(h[:, None] - h[None], axis=-1)
    same, off = ids[:, None] == ids[None], ~np.eye(len(ids), dtype=bool)
    d_same, d_diff = D[same & off].mean(), D[~same].mean()
    assert d_diff > 1.5 * d_same, (d_same, d_diff)
    nn = ids[(D + 1e9 * np.eye(len(ids))).argmin(1)]
    assert np.mean(nn == ids) > 0.6, np.mean(nn == ids)  # chance: 1 / n_layouts = 0.25


def test_staged_phases_touch_only_their_own_parameters():
    from zsbfm.data import collect

    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=2, episodes_per_layout=4, d=8,
                              f_pre_hidden=(8,), f_pre_out=8, f_hidden=(8,), b_hidden=(8,), batch_size=8,
                              enc_batch=2, enc_embed=8, enc_mlp=8, pred_hidden=(8,),
                              enc_steps=1000, steps=2000, eval_ema=0.5)
    env = zsbfm.make_env("fourrooms", n_train=2)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 4))(jax.random.PRNGKey(0))
    s0 = jax.jit(agent.init)(jax.random.PRNGKey(0))  # compiled once: eager init costs ~15 s here
    same = lambda a, b: all(np.array_equal(x, y) for x, y in
                            zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))
    update = jax.jit(agent.update)
    s1, m1 = update(s0, ds, jax.random.PRNGKey(1), jnp.int32(3))              # encoder phase
    assert same(s0.params.F, s1.params.F) and same(s0.params.B, s1.params.B)
    assert not same(s0.params.enc["encoder"], s1.params.enc["encoder"])
    assert np.isfinite(m1["enc_mse"]) and m1["fb_loss"] == 0  # a placeholder of the FB phase
    assert set(agent.phase_metrics(3, m1)) == {"enc_mse", "enc_kl", "h_norm", "enc_nce"}  # enc_contrast > 0
    s2, m2 = update(s1, ds, jax.random.PRNGKey(2), jnp.int32(1000))           # first FB step
    assert same(s1.params.enc["encoder"], s2.params.enc["encoder"])
    assert not same(s1.params.F, s2.params.F)
    assert np.isfinite(m2["fb_loss"]) and m2["enc_mse"] == 0
    # the evaluation average counts FB updates only, and reads the online encoder
    assert int(s1.average.n) == 0 and int(s2.average.n) == 1
    assert same(agent.eval_params(s2).F, s2.params.F) and agent.eval_params(s2).enc is s2.params.enc
    fb_names = set(agent.phase_metrics(1000, m2))
    assert "fb_loss" in fb_names and set(m2) - fb_names == {"enc_mse", "enc_kl", "h_norm", "enc_nce"}
    assert not fb_names & set(agent.ENCODER_METRICS)
    # the h table holds the standardised mu of every episode
    standardized = jax.jit(lambda enc: agent.standardize(enc, agent.encode(enc, ds.obs[:, :-1], ds.action,
                                                                           ds.obs[:, 1:])[0]))
    np.testing.assert_allclose(np.asarray(s2.h_table[:, 0]), np.asarray(standardized(s2.params.enc)),
                               rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("source", ["episode", "dataset"])
def test_rfb_state_half_of_z_comes_from_the_configured_states(source):
    """With z_mix = 1 every training z is B(s): with rfb_z_states="episode" s is a state of
    the row's own episode; with "dataset" s is any stored state, so many rows get B of a cell
    their episode never visited (a 100-step random walk covers part of the four rooms)."""
    from zsbfm.data import collect, sample_transitions

    env = zsbfm.make_env("fourrooms", n_train=2)
    ds = collect(env, jax.random.PRNGKey(0), env.contexts("train"), 20)
    cfg = zsbfm.Config.preset("fourrooms", "rfb", d=8, f_pre_hidden=(8,), f_pre_out=8, f_hidden=(8,),
                              b_hidden=(8,), z_mix=1.0, rfb_z_states=source, n_train_layouts=2,
                              episodes_per_layout=20)
    agent = make_agent(cfg, env)
    state = agent.init(jax.random.PRNGKey(1))
    n = 1000
    batch = sample_transitions(jax.random.PRNGKey(2), ds, n)
    h = jax.random.normal(jax.random.PRNGKey(3), (n, 8))
    z = np.asarray(agent.train_z(state, ds, batch, h, jax.random.PRNGKey(4)))
    cells = jnp.stack(jnp.meshgrid(jnp.arange(11.0), jnp.arange(11.0)), -1).reshape(-1, 2)
    Bset = np.asarray(agent.backward(state.params.B, cells))
    nearest = np.argmin(np.linalg.norm(z[:, None] - Bset[None], axis=-1), axis=1)
    assert np.min(np.linalg.norm(z - Bset[nearest], axis=-1)) < 1e-4  # every z is B of a cell
    obs = np.asarray(ds.obs)
    episode = np.asarray(batch.episode)
    visited = [{tuple(c) for c in obs[e, 1:]} for e in episode]
    in_episode = np.mean([tuple(np.asarray(cells[k])) in v for k, v in zip(nearest, visited)])
    if source == "episode":
        assert in_episode == 1.0
    else:
        assert in_episode < 0.6, in_episode  # measured 0.34


@pytest.mark.slow  # ~1 min: three compiles
def test_a_k_episode_h_table_holds_each_episode_pooled_with_another_of_its_layout():
    """context_episodes=2: after the encoder phase the h table of episode e is the standardised
    mu of the context {e, p} for an episode p != e of e's layout (every candidate p is tried)."""
    from zsbfm.data import collect

    per = 4
    cfg = zsbfm.Config.preset("fourrooms", "bfb", n_train_layouts=2, episodes_per_layout=per, d=8,
                              f_pre_hidden=(8,), f_pre_out=8, f_hidden=(8,), b_hidden=(8,), batch_size=8,
                              enc_batch=2, enc_embed=8, enc_mlp=8, pred_hidden=(8,),
                              enc_steps=1000, steps=2000, context_episodes=2)
    env = zsbfm.make_env("fourrooms", n_train=2)
    agent = make_agent(cfg, env)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), per))(jax.random.PRNGKey(0))
    update = jax.jit(agent.update)
    s1, m1 = update(jax.jit(agent.init)(jax.random.PRNGKey(0)), ds, jax.random.PRNGKey(1), jnp.int32(3))
    assert np.isfinite(m1["enc_mse"]) and np.isfinite(m1["enc_nce"])
    s2, _ = update(s1, ds, jax.random.PRNGKey(2), jnp.int32(1000))            # builds the table
    table = np.asarray(s2.h_table[:, 0])
    pair_h = jax.jit(lambda enc, e: agent.standardize(enc, agent.encode(
        enc, ds.obs[e, :-1], ds.action[e], ds.obs[e, 1:], episodes=True)[0]))
    for e in range(2 * per):
        first = e - e % per
        candidates = [np.asarray(pair_h(s2.params.enc, jnp.array([e, p])))
                      for p in range(first, first + per) if p != e]
        errors = [np.abs(c - table[e]).max() for c in candidates]
        assert min(errors) < 1e-4, (e, errors)
    # a pair {e, p} is one context whichever of the two it is drawn for; each layout's 4
    # episodes make at least 2 distinct pairs, and no two layouts share one
    assert len({tuple(np.round(row, 3)) for row in table}) >= 4
