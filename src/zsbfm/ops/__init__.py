"""Small maths used by the networks and agents."""

from zsbfm.ops.matmul import matmul
from zsbfm.ops.sphere import project_to_sphere, sample_sphere

__all__ = ["matmul", "project_to_sphere", "sample_sphere"]
