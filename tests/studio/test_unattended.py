"""The unattended-scan set-up shared by the CLI and the window (lfstudio/studio/unattended.py): the
end-of-day command (time limit, output, failure notified), options checked before anything starts."""

from __future__ import annotations

import json

import pytest

from lfstudio.errors import InputError
from lfstudio.scan.events import ScanState
from lfstudio.studio.unattended import Unattended, UnattendedOptions
from tests.scan.receivers import Receiver
from tests.scan.test_notify import instant_engine


def run_scan(tmp_path, options, **kw):
    said = []
    unattended = Unattended.open(options, say=said.append)
    engine, ds = instant_engine(tmp_path, **kw)
    unattended.attach(engine, ds)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED
    assert unattended.wait_on_finish(120)
    unattended.close()
    return unattended, said, ds


def test_the_on_finish_command_runs_once_with_the_outcome_and_its_output_is_said(tmp_path):
    marker = tmp_path / "lights.txt"
    options = UnattendedOptions(on_finish=f"echo lights off after $LFSTUDIO_DONE of $LFSTUDIO_TOTAL "
                                          f"$LFSTUDIO_SCAN_OUTCOME; echo off >> {marker}")
    unattended, said, ds = run_scan(tmp_path, options)
    assert unattended.on_finish_result["returncode"] == 0 and not unattended.on_finish_result["error"]
    assert "--on-finish: | lights off after 6 of 6 finished" in said and said[-1] == "--on-finish: done"
    assert marker.read_text() == "off\n"                  # once


def test_a_failing_or_hanging_on_finish_command_is_stopped_and_notified(tmp_path):
    receiver = Receiver()
    try:
        options = UnattendedOptions(notify=[receiver.url("/hook?key=S3CRET")],
                                    on_finish=f"echo cannot reach {receiver.url('/lights?key=S3CRET')}; sleep 600",
                                    on_finish_timeout_s=1)
        unattended, said, ds = run_scan(tmp_path, options)
        result = unattended.on_finish_result
        assert result["timed_out"] and result["error"] == "did not end within 1 s: stopped"
        assert f"cannot reach {receiver.url('/lights?key=S3CRET')}" in result["output"]   # its output, as it was
        failed = [json.loads(p["body"]) for p in receiver.posts if b"on-finish-failed" in p["body"]]
        assert len(failed) == 1 and "did not end within 1 s" in failed[0]["message"]
        assert "S3CRET" not in failed[0]["message"] and "running echo cannot reach http://127.0.0.1" in said[1]
    finally:
        receiver.close()
    options = UnattendedOptions(on_finish="exit 7")
    unattended, said, ds = run_scan(tmp_path / "b", options)
    assert unattended.on_finish_result["error"] == "failed with exit status 7"


@pytest.mark.parametrize("options, words", [
    (UnattendedOptions(on_finish="   "), "--on-finish: the command is empty"),
    (UnattendedOptions(on_finish="true", on_finish_timeout_s=0), "--on-finish-timeout-s: "),
    (UnattendedOptions(auto_resume=-1), "--auto-resume: "),
    (UnattendedOptions(status_token="new"), "--status-token: is for the status page"),
])
def test_bad_options_are_refused_naming_the_option(options, words):
    with pytest.raises(InputError) as err:
        Unattended.open(options)
    assert str(err.value).startswith(words)


def test_the_window_names_its_own_fields(receiver=None):
    names = {"notify": "Settings → Unattended scans → Notify", "smtp": "Settings → SMTP server",
             "status_http": "Settings → Status page address", "status_token": "Settings → Status page token",
             "status_linger_s": "Settings → Status page after the scan", "auto_resume": "Settings → Auto-resume",
             "on_finish": "Settings → When the scan ends", "on_finish_timeout_s": "Settings → Time limit"}
    with pytest.raises(InputError, match="^Settings → Unattended scans → Notify: unknown scheme 'gopher'"):
        Unattended.open(UnattendedOptions(notify=["gopher://x/y"], names=names))


def test_on_finish_is_contained_its_leftovers_ended_notified_and_logged_in_one_line(tmp_path, caplog):
    """A command that leaves a setsid'd process holding its output (#42 item 9): ended at the limit,
    nothing waits longer, one warning line, one on-finish-failed notice."""
    import logging

    from tests.scankill import gone

    pidfile = tmp_path / "left.pid"
    receiver = Receiver()
    try:
        options = UnattendedOptions(notify=[receiver.url("/hook")], on_finish_timeout_s=1,
                                    on_finish=f"setsid sh -c 'echo $$ > {pidfile}; exec sleep 600' & echo lights off")
        with caplog.at_level(logging.INFO, logger="lfstudio.studio.unattended"):
            unattended, said, ds = run_scan(tmp_path, options)
        assert receiver.wait_for(lambda posts: any(b"on-finish-failed" in p["body"] for p in posts))
    finally:
        receiver.close()
    result = unattended.on_finish_result
    assert result["timed_out"] and result["error"] == "left processes running past the 1 s time limit: stopped"
    assert gone(int(pidfile.read_text()))
    assert "--on-finish: | lights off" in said
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "\n" not in warnings[0] and "time limit" in warnings[0]


def test_on_finish_output_is_capped_in_memory_and_in_the_log(tmp_path, caplog):
    import logging

    from lfstudio.support.children import HEAD_LINES, KEEP_BYTES, TAIL_LINES

    options = UnattendedOptions(on_finish="seq 1 100000; head -c 5000000 /dev/zero | tr '\\0' x")
    with caplog.at_level(logging.INFO, logger="lfstudio.studio.unattended"):
        unattended, said, ds = run_scan(tmp_path, options)
    result = unattended.on_finish_result
    assert not result["error"] and result["output_bytes"] > 5_000_000 and len(result["output"]) <= KEEP_BYTES + 10
    output_lines = [r for r in caplog.records if "--on-finish: |" in r.getMessage()]
    assert len(output_lines) == HEAD_LINES + 1 + TAIL_LINES
    assert max(len(r.getMessage()) for r in caplog.records) < 3000


def test_closing_says_when_it_waits_for_a_notification_still_on_its_way(tmp_path):
    """After a Ctrl+C the CLI waits (at most its bound) for the last notices: it says so, instead of
    sitting silent while an endpoint does not answer."""
    from lfstudio.scan.notify import Notifier
    from tests.scan.receivers import DeadEndpoint

    dead = DeadEndpoint()
    said: list[str] = []
    try:
        notifier = Notifier([dead.url()], dataset="day1", timeout_s=600)
        unattended = Unattended(UnattendedOptions(notify=[dead.url()]), notifier, say=said.append)
        notifier.notify("aborted", "stopped by Ctrl+C")
        assert dead.accepted.wait(30)                    # the notice is on its way, unanswered
        unattended.close(timeout_s=0.2)
    finally:
        dead.close()
    assert notifier.wait_idle(30)           # the held notice failed with the endpoint: logged in this test
    assert said == ["--notify: delivering the last notifications (at most 0.2 s)"]
