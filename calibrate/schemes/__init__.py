"""Experiments of the seeds on top of the calibration library.

* :mod:`calibrate.schemes.compensate`: virtual control points and the four compensation schemes
  of a staring camera (seed 002);
* :mod:`calibrate.schemes.thermal`: temperature-driven installation angles (seed 002);
* :mod:`calibrate.schemes.autocollimation`: autocollimation self-calibration of the focal length
  and axis rotations (seed 004).
"""
