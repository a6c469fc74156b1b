"""Measuring a step (PROTOCOL.md 4): image, geometry, coverage and uncertainty metrics, the real LPIPS
weights, each metric's table metadata, and the evaluation of one step's model."""
