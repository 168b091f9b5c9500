"""Frames, time scales, orbit and attitude samples, geodesy and star directions."""
