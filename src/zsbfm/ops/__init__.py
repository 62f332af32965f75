"""Small maths used by the agents."""

from zsbfm.ops.linalg import spd_inverse
from zsbfm.ops.sphere import project_to_sphere, sample_sphere

__all__ = ["project_to_sphere", "sample_sphere", "spd_inverse"]
