"""Simulators: the virtual studio (scene + renderer with ground truth), the simulated camera, the DNG writer, the GRBL controller on a pty."""
