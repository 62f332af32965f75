"""Algorithms behind one protocol (see `zsbfm.agents.base`)."""

from zsbfm.agents.base import Agent, Context, Task
from zsbfm.agents.belief import BeliefFBAgent, BeliefState, RotationFBAgent
from zsbfm.agents.fb import FBAgent, FBParams, FBState, fb_loss, ortho_loss
from zsbfm.agents.oracle import OracleFBAgent
from zsbfm.agents.random import RandomAgent
from zsbfm.agents.sf import HILPAgent, LaplacianAgent, SFAgent
from zsbfm.names import add_algo

AGENTS = {"fb": FBAgent, "bfb": BeliefFBAgent, "rfb": RotationFBAgent, "oracle": OracleFBAgent,
          "hilp": HILPAgent, "lap": LaplacianAgent, "random": RandomAgent}


def register_agent(name: str, cls) -> None:
    """Make `cls(cfg, env)` the agent of Config.algo == name (docs/extending.md)."""
    AGENTS[name] = cls
    add_algo(name)  # Config accepts the name from now on


def make_agent(cfg, env) -> Agent:
    """The agent for cfg.algo on `env`."""
    if cfg.algo not in AGENTS:
        raise ValueError(f"unknown algo {cfg.algo!r}; available: {', '.join(AGENTS)}")
    return AGENTS[cfg.algo](cfg, env)


__all__ = ["Agent", "Context", "Task", "FBAgent", "OracleFBAgent", "HILPAgent", "LaplacianAgent",
           "SFAgent", "RandomAgent", "BeliefFBAgent", "RotationFBAgent", "BeliefState", "FBParams", "FBState", "fb_loss",
           "ortho_loss", "make_agent", "register_agent", "AGENTS"]
