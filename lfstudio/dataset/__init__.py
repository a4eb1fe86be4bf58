"""The dataset folder: manifest, raw files, thumbnails, processed views, calibration.

See ``docs/dataset-format.md``. Every write is atomic (:mod:`lfstudio.dataset.atomic`).
"""

from lfstudio.dataset.manifest import FORMAT, VERSION, Dataset, validate_manifest
from lfstudio.dataset.paths import resolve_inside, view_stem

__all__ = ["FORMAT", "VERSION", "Dataset", "validate_manifest", "resolve_inside", "view_stem"]
