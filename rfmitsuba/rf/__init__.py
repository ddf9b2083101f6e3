"""Radio physics: the array, the PAS grid, the Bartlett beamformer (NumPy reference and Dr.Jit op), image sources."""
