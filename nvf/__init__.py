"""Neural Visibility Field (NVF) and its baselines: plain typed PyTorch, no Hydra, no file I/O."""
