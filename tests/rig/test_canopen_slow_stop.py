"""STOP on a CANopen drive that is slow, not lost: its SDO read in flight when STOP comes is
interrupted after 20 ms so that the quick stop can take the node's one SDO channel. The read was
then reported as "does not answer" and the drive marked lost. Now the read is asked again once the
quick stop is out, and the quick stop survives the interrupted exchange's late answer. Emulated
drives on python-can's virtual bus with real python-canopen stacks at both ends. Drive x answers
every read 0.5 s late, 25 times STOP's 20 ms; nothing here waits on a duration."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

from lfstudio.rig.cia402 import CONTROL, QUICK_STOP, SIZES, STATUS
from lfstudio.rig.motion import RigState
from lfstudio.rig.profile import load_rig
from lfstudio.studio.devices import open_rig
from lfstudio.studio.simulated import start_drive_emulator

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
HANG_GUARD_S = 30.0


def test_a_read_interrupted_by_stop_is_asked_again_and_the_drive_stays_connected():
    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, "canopen", time_scale=0)
    link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=5.0)
    pool = ThreadPoolExecutor(2)
    try:
        c = link.controller
        c.connect()
        c.home()
        x_link, x = c.links[0], emulator.pair.axes[0]
        interrupted = threading.Event()
        sdo = x_link.node.sdo
        real_interrupt = sdo.interrupt

        def interrupt() -> None:
            interrupted.set()
            real_interrupt()

        sdo.interrupt = interrupt
        x.setup.answer_delay_s = 0.5
        emulator.time_scale = 1.0                       # the delay counts in real time now
        read = pool.submit(x_link.read, STATUS, 0, *SIZES[STATUS])
        while not x_link._lock.locked() and not read.done():
            pass                                        # until the read is in flight on x's SDO channel
        stop = pool.submit(x_link.write_now, CONTROL, 0, QUICK_STOP, *SIZES[CONTROL])
        stop.result(timeout=HANG_GUARD_S)               # the quick stop went out, no error
        status_word = read.result(timeout=HANG_GUARD_S)  # the slow read was asked again, not lost
        assert interrupted.is_set()                     # STOP did interrupt it
        assert isinstance(status_word, int)
        assert [v for n, i, _, v in emulator.pair.journal if n == x.name and i == CONTROL][-1] == QUICK_STOP
        x.setup.answer_delay_s = 0.0
        c._last_t = 0.0                                 # the next status reads the drives
        st = c.status()
        assert c.connected and st.state is not RigState.DISCONNECTED, st.message
    finally:
        pool.shutdown(wait=False)
        link.close()
        emulator.close()


def test_a_command_whose_write_stop_cuts_short_is_stopped_and_the_drive_not_lost():
    """The same slow drive (every answer, a write's too, 0.5 s late), STOP while a move's write to it
    is in flight: the write is cut short for the quick stop; the move ends as stopped by STOP (it
    ended with the drive marked lost: "does not answer … interrupted by STOP")."""
    from lfstudio.rig.cia402 import MotionStopped

    rig = load_rig(RIG_NAME)
    emulator = start_drive_emulator(rig, "canopen", time_scale=0)
    link = open_rig(emulator.word, rig, doing="test", lock=False, connect=False, timeout_s=5.0)
    pool = ThreadPoolExecutor(1)
    try:
        c = link.controller
        c.connect()
        c.home()
        x_link, x = c.links[0], emulator.pair.axes[0]
        sdo = x_link.node.sdo
        writing = threading.Event()
        real_download = sdo.download

        def download(*args, **kw):
            writing.set()                               # a write to drive x is on its way
            return real_download(*args, **kw)

        sdo.download = download
        x.setup.answer_delay_s = 0.5
        emulator.time_scale = 1.0
        move = pool.submit(c.move_to, 100.0, 0.0)
        assert writing.wait(HANG_GUARD_S)
        c.stop()
        failure = move.exception(timeout=HANG_GUARD_S)
        assert isinstance(failure, MotionStopped), failure
        assert "stopped by STOP" in str(failure) and "\n" not in str(failure)
        assert c.connected
        x.setup.answer_delay_s = 0.0
        c._last_t = 0.0
        st = c.status()
        assert st.state is not RigState.DISCONNECTED, st.message
        assert [v for n, i, _, v in emulator.pair.journal if n == x.name and i == CONTROL].count(QUICK_STOP) >= 1
    finally:
        pool.shutdown(wait=False)
        link.close()
        emulator.close()
