"""Shapes: procedural families, mesh loading, mass properties, resting poses and surface sampling."""
