"""Neural network modules (flax.linen)."""

from zsbfm.nets.fb import BackwardNet, ForwardNet, TwinForward
from zsbfm.nets.mlp import MLP

__all__ = ["MLP", "ForwardNet", "TwinForward", "BackwardNet"]
