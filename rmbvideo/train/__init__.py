"""Training data generation and the RMB-Net training loop."""
