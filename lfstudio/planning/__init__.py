"""Scene planning: the plan object (inputs -> grid, aperture, focus, time, warnings) and the camera/lens/rig
presets. The formulas themselves are in :mod:`lfstudio.optics` (one layer below every stage)."""
