"""Scanning: the scan plan (which positions, in which order) and the engine that runs it."""

from lfstudio.scan.scan_plan import ORDERS, PlannedView, ScanPlan, grid_order

__all__ = ["ORDERS", "PlannedView", "ScanPlan", "grid_order"]
