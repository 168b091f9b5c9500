"""Sensor models: push-broom, its attitude correction, GEO staring, RPC and its fit, laboratory cameras, grids, synthetic examples and model comparison."""
