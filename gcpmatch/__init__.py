"""GCP extraction: reference chips in scene geometry, SIFT coarse matching, phase correlation.

Depends on :mod:`sensor_models` only.
"""
