"""The dataset quality stage: is this capture good enough to publish? Judged from the pixels alone.

``check_dataset`` (batch, ``lfstudio check``) writes ``DATASET/quality.json`` and
``DATASET/quality/`` (heat maps, disparity map, histograms, report.html); ``LiveChecker`` checks
each view as a scan captures it. See ``docs/quality.md``.
"""

from lfstudio.quality.check import QUALITY_NAME, QualityReport, check_dataset, load_quality
from lfstudio.quality.verdicts import Thresholds

__all__ = ["QUALITY_NAME", "QualityReport", "Thresholds", "check_dataset", "load_quality"]
