"""The Qt desktop application on top of the Qt-free core. Panels talk to :class:`AppState`, not to each other."""
