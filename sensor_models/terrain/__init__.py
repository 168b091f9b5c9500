"""Terrain: geoid, DEM access, line-of-sight intersection with the ground, DEM windows and footprints."""
