"""The names the code accepts for its choices: algorithms, preset sizes, and the values of
Config's string fields.

This module imports nothing of zsbfm's, so every layer reads the names from below it:
Config validates against them, nets and agents branch on them, and the command line's help
lists them (zsbfm.cli), so a name added here is accepted and documented at once.
Environments are named by their own registry (zsbfm.envs.registry), which is below Config
too.
"""

from __future__ import annotations

ALGOS = ("fb", "bfb", "rfb", "oracle", "hilp", "lap", "random")  # the built-in agents (zsbfm.agents.AGENTS)
BELIEF_ALGOS = ("bfb", "rfb")          # infer h with the context encoder
# preset sizes (Config.preset). "long": the gridworlds' longer table (docs/results.md); "paper":
# Table 4; "authors": the authors' public code (BeliefConditionedFB: gridworlds; README
# "Presets" says where it and Table 4 disagree)
SIZES = ("cpu", "long", "paper", "authors")
ENCODER_MODES = ("staged", "joint")
# what Belief-FB gives F as h: the encoder's mean "mu" | its prediction of the layout's "context" features
H_FROM = ("mu", "context")
CONTEXT_LOSSES = ("mse", "bce")  # the loss of Belief-FB's context head (agents/belief.py)
# what that head regresses on: the layout's whole feature "map" | the features the context
# "revealed" (the map where its transitions show it, the train layouts' mean elsewhere)
CONTEXT_TARGETS = ("map", "revealed")
CONTEXT_READS = ("head", "evidence")  # how Belief-FB reads h = the map off a context (agents/belief.py read_context)
ENC_POOLS = ("mean", "max", "cells", "evidence")  # how the context encoder pools its tokens (nets/encoder.py)
TARGET_POLICIES = ("greedy", "boltzmann", "uniform")
SPLUS = ("batch", "states", "exact")    # the s+ estimator of the FB loss (agents/fb.py)
F_ARCHS = ("reference", "normed_trunk", "mlp")  # F's (and with "mlp" B's) layer layout (nets/fb.py)
TWIN_TARGETS = ("mean", "min")           # how the twin heads' target measures combine (agents/fb.py)
OBS_ENCODINGS = ("onehot", "raw", "unscaled")  # the networks' observation input (agents/fb.py obs_features)
# where Rotation-FB's B(s) half of the training z comes from (agents/belief.py): a state of
# h's own "episode" | any "dataset" state (the paper's "s ~ D", the authors' code, FB's)
RFB_Z_STATES = ("episode", "dataset")
DATA_POLICIES = ("expert", "random")
EXPERT_SOURCES = ("shipped", "train")
ON_NONFINITE = ("stop", "drop")         # what a run does when a seed's losses or parameters go non-finite (zsbfm.nonfinite)

_registered_algos: list[str] = []  # names added by zsbfm.agents.register_agent


def add_algo(name: str) -> None:
    """Accept `name` as Config.algo (zsbfm.agents.register_agent calls this)."""
    if name not in ALGOS and name not in _registered_algos:
        _registered_algos.append(name)


def algo_names() -> tuple[str, ...]:
    """Every algorithm Config.algo accepts: the built-in ones, then the registered ones."""
    return ALGOS + tuple(_registered_algos)
