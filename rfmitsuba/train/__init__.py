"""Training: configuration, the loop and run folder, the loss, density strategies."""
