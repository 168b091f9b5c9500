"""Scene simulation with known truth: procedural reference data and push-broom rendering.

The simulator uses the very sensor-model code that localization uses, so a rendered scene is
exactly what its TRUE model says; the manifest written beside it carries the LAB model a user
would receive.
"""
