"""lfstudio: plan, capture, calibrate, process and export dense light fields.

The core package (everything except :mod:`lfstudio.gui`) never imports Qt.
Data flows one way: plan -> rig/scan -> dataset -> calibration -> processing -> export.
"""

__version__ = "0.1.0"
