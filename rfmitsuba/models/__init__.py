"""Fields: one Field protocol, a registry by name, and one file per model family."""
