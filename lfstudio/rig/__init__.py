"""Devices: motion controllers and cameras. Synchronous drivers + one generic threaded worker."""
