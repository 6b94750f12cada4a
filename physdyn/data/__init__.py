"""Datasets: the Zarr store, training windows, normalisation and the LightningDataModule."""
