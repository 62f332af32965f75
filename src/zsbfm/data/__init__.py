"""Offline data: on-device collection, episode-major datasets, jittable samplers."""

from zsbfm.data.collect import collect, rollout, uniform_policy
from zsbfm.data.dataset import Dataset, load_dataset, save_dataset
from zsbfm.data.samplers import (Transitions, geometric_offsets, sample_future, sample_states,
                                 sample_transitions, sample_windows)

__all__ = ["Dataset", "Transitions", "collect", "rollout", "uniform_policy", "load_dataset",
           "save_dataset", "sample_transitions", "sample_states", "sample_future",
           "sample_windows", "geometric_offsets"]
