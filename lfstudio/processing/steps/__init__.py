"""One module per processing step. Each is plain numpy/OpenCV on (h, w, 3) uint16 RGB arrays."""
