"""Supportability: the log file, component versions (``lfstudio doctor``, Help → About), the user guide;
the OS-level locks of ports, cameras and dataset folders (:mod:`lfstudio.support.locks`).

Qt-free like the rest of the core; the GUI's crash dialog and Help menu build on these.
"""
