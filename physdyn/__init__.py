"""physdyn: learn to predict the physical dynamics of unseen 3D objects (Rempe et al., WACV 2020)."""

__version__ = "0.1.0"
