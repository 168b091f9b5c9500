"""HTML reports with PNG figures.

* :func:`write_report` (:mod:`calibrate.report.calibration`): calibration from GCPs, with the
  check-point accuracy before and after;
* :func:`write_star_report` (:mod:`calibrate.report.star_report`): star-track calibration.
"""

from calibrate.report.calibration import write_report
from calibrate.report.star_report import write_star_report

__all__ = ["write_report", "write_star_report"]
