"""Post-processing: RAW captures → rectified 16-bit views (the paper's seven steps).

``profile`` holds the switchable, parameterised steps (``processing.toml``); ``steps/`` one module
per step; ``worker`` the per-view task; ``pipeline`` runs it over a dataset through an executor
from ``executors`` (a local process pool or a Dask cluster) with progress, cancel and resume.
"""
