"""Datasets: the Zarr store, training windows, normalisation and the LightningDataModule."""

# A simulation's split, as stored in sims/split (docs/dataset-format.md): the one definition of the names.
SPLIT_NAMES = {0: "train", 1: "val", 2: "test"}
SPLITS = {name: index for index, name in SPLIT_NAMES.items()}
