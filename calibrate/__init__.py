"""Calibration of sensor models from GCPs and stars, accuracy reports, batch runs, and the CLI."""
