"""Small maths used by the agents."""

from zsbfm.ops.sphere import project_to_sphere, sample_sphere

__all__ = ["project_to_sphere", "sample_sphere"]
