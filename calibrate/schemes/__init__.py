"""Experiments of the seeds on top of the calibration library.

* :mod:`calibrate.schemes.compensate`: the four compensation schemes of a staring camera on
  virtual control points (seed 002), with :mod:`calibrate.schemes.virtual_points` (the VCPs and
  the errors on them), :mod:`calibrate.schemes.compensation_study` (seed 002's tables 1-3) and
  :mod:`calibrate.schemes.compensation_outputs` (its table, summary and figures), and
  :mod:`calibrate.schemes.paper_flow` (seed 002's own data flow: the interior from the lab's
  camera-frame grid, the exterior from the VCPs);
* :mod:`calibrate.schemes.thermal`: temperature-driven installation angles (seed 002), with
  :mod:`calibrate.schemes.thermal_model` (the angles against time of day),
  :mod:`calibrate.schemes.thermal_simulation` (the drifting test bed) and
  :mod:`calibrate.schemes.thermal_figures`;
* :mod:`calibrate.schemes.autocollimation`: autocollimation self-calibration of the focal length
  and axis rotations (seed 004).
"""
