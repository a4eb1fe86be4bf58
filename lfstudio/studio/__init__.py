"""The studio: the one Qt-free place that turns device descriptions into running drivers and runs
a scan session on them. The CLI and the GUI are thin layers over it.

- the OS-level locks (one process per serial port, camera and dataset) are :mod:`lfstudio.support.locks`,
  below the dataset layer: the rule for a new dataset folder and the importers read them too;
- :mod:`lfstudio.studio.devices`: ``sim`` / ``instant`` / a serial port, ``sim`` / ``gphoto2`` /
  ``folder:PATH`` / ``instant`` -> connected drivers (:func:`~lfstudio.studio.devices.open_studio`);
- :mod:`lfstudio.studio.simulated`: the simulated studio wired together, and the only door to
  :mod:`lfstudio.sim` for the rest of lfstudio;
- :mod:`lfstudio.studio.session`: a scan session (dataset lock, create or resume the dataset with
  its own devices, homing policy, hand-over to the scan engine).
"""
