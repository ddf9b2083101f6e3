"""Bottom layer: the Dr.Jit backend and libLLVM discovery, errors, atomic writes, typed TOML/JSON configs, progress bars, plots."""
