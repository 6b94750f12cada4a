"""Simulation: the PyBullet world, impulses, trajectory recording and parallel dataset generation."""
