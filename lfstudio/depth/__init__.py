"""Depth and points from the light field: the sparse point cloud (:mod:`lfstudio.depth.points`),
dense per-view disparity and depth (:mod:`lfstudio.depth.dense`), their files (:mod:`lfstudio.depth.files`)
and the long job that stores dense maps in the dataset (:mod:`lfstudio.depth.run`).

Layer: above calibration (it reads the calibration and its features), below the export (which writes
the points into COLMAP/nerfstudio models and the maps beside the views). Qt-free.
"""
