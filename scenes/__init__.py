"""Scenes: cube maps, skies, environment and mesh I/O, the Embree G-buffer and the scene registry."""
