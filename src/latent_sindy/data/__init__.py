"""Trajectory data: collection (workers, resume), the HDF5 trajectory file, training windows.

    latent-sindy collect --out data/push.h5 --trajectories 200 --workers 2 --seed 0
"""
