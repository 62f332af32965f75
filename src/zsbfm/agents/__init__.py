"""Algorithms behind one protocol (see `zsbfm.agents.base`)."""

from zsbfm.agents.base import Agent, Context, Task
from zsbfm.agents.belief import BeliefFBAgent, BeliefState, RotationFBAgent
from zsbfm.agents.fb import FBAgent, FBParams, FBState, fb_loss, ortho_loss

AGENTS = {"fb": FBAgent, "bfb": BeliefFBAgent, "rfb": RotationFBAgent}


def make_agent(cfg, env) -> Agent:
    """The agent for cfg.algo on `env`."""
    if cfg.algo not in AGENTS:
        raise ValueError(f"unknown algo {cfg.algo!r}; available: {', '.join(AGENTS)}")
    return AGENTS[cfg.algo](cfg, env)


__all__ = ["Agent", "Context", "Task", "FBAgent", "BeliefFBAgent", "RotationFBAgent", "BeliefState", "FBParams", "FBState", "fb_loss",
           "ortho_loss", "make_agent", "AGENTS"]
