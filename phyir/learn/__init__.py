"""Learning: training datasets, losses, the four-stage training loop, weights files."""
