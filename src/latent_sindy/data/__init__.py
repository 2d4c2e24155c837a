"""Data: :class:`SequenceData` (images, actions, optional states, names, dt), its HDF5 file,
training windows and normalisation. Collection belongs to the worlds.

    from latent_sindy.data import read_sequences
    data = read_sequences("data/push.h5")
"""

from latent_sindy.data.sequence import SPLITS, SequenceData, concatenate, seeded_split
from latent_sindy.data.store import read_sequences, write_sequences

__all__ = ["SPLITS", "SequenceData", "concatenate", "read_sequences", "seeded_split",
           "write_sequences"]
