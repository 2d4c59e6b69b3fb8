"""The extendable SPARE dataset: per-sequence generation, the sharded HDF5 store, manifest and
splits, and torch datasets (stored and on-the-fly)."""
