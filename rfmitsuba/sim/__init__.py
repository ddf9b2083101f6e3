"""Simulation: scene builder and geometry, the person (mesh and walk), the Sionna RT wrapper, dataset generation."""
