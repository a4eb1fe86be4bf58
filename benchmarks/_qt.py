"""Qt helpers shared by the GUI benchmarks (which run offscreen)."""

from __future__ import annotations


def spin_until(cond, timeout_s: float) -> bool:
    """Run the event loop (idle-waiting, as the application does) until ``cond()`` holds."""
    from PySide6.QtCore import QEventLoop, QTimer

    loop = QEventLoop()
    check = QTimer()
    check.setInterval(20)
    check.timeout.connect(lambda: loop.quit() if cond() else None)
    QTimer.singleShot(int(timeout_s * 1000), loop.quit)
    if not cond():
        check.start()
        loop.exec()
        check.stop()
    return cond()
