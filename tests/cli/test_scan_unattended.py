"""``lfstudio scan`` left alone: --notify (a real local receiver), bad input refused before anything
starts."""

from __future__ import annotations

import json

import pytest

from tests.scan.receivers import Receiver


@pytest.fixture
def receiver():
    r = Receiver()
    yield r
    r.close()


def test_scan_notifies_a_local_receiver_and_logs_no_secret(run_cli, tmp_path, receiver):
    logs = tmp_path / "logs"
    url = receiver.url("/hook/S3CR3TPATH?key=S3CR3TKEY")
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", tmp_path / "day1",
                "--time-scale", "0", "--notify", url, env={"LFSTUDIO_LOG_DIR": str(logs)})
    assert r.returncode == 0, r.stderr
    assert f"notifications to http://127.0.0.1:{receiver.port}/…" in r.stderr
    bodies = [json.loads(p["body"]) for p in receiver.posts]
    assert [b["event"] for b in bodies] == ["started", "finished"]
    assert (bodies[-1]["dataset"], bodies[-1]["done"], bodies[-1]["total"]) == ("day1", 6, 6)
    logged = "".join(p.read_text(errors="replace") for p in logs.rglob("*") if p.is_file())
    assert "scan finished" in logged                        # the log file was written ...
    assert "S3CR3T" not in logged and "S3CR3T" not in r.stderr       # ... without the secret


@pytest.mark.parametrize("args, words", [
    (["--notify", "ftp://example.com/x"], "--notify: unknown scheme 'ftp'"),
    (["--notify", "http://example.com:http/x"], "--notify: http://example.com… is not a well-formed URL"),
    (["--notify", "mailto:alice@lab.example"], "--notify: a mailto: target needs an SMTP server"),
    (["--smtp", "ftp://mail.example"], "--smtp: "),
])
def test_bad_unattended_options_are_one_line_and_nothing_starts(run_cli, tmp_path, args, words):
    out = tmp_path / "day1"
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", out,
                "--time-scale", "0", *args)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and words.split("…")[0] in lines[0], lines
    assert not out.exists()


def test_on_finish_runs_when_the_scan_ends_and_its_output_is_shown(run_cli, tmp_path):
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", tmp_path / "day1",
                "--time-scale", "0", "--auto-resume", "3",
                "--on-finish", "echo lights off after $LFSTUDIO_DONE of $LFSTUDIO_TOTAL: $LFSTUDIO_SCAN_OUTCOME")
    assert r.returncode == 0, r.stderr
    assert "--on-finish: | lights off after 6 of 6: finished" in r.stderr


@pytest.mark.parametrize("args, words", [
    (["--auto-resume", "many"], "--auto-resume"),
    (["--on-finish-timeout-s", "0"], "--on-finish-timeout-s"),
    (["--on-finish", " "], "--on-finish: the command is empty"),
])
def test_bad_auto_resume_and_on_finish_options(run_cli, tmp_path, args, words):
    out = tmp_path / "day1"
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", out, *args)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and words in lines[0], r.stderr
    assert not out.exists()


def test_a_given_status_token_is_never_printed_nor_logged_and_a_new_one_printed_once(run_cli, tmp_path):
    logs = tmp_path / "logs"
    token = "MyOwnStatusToken-0123456789"
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", tmp_path / "day1",
                "--time-scale", "0", "--status-http", "127.0.0.1:0", "--status-token", token,
                "--status-linger-s", "0", env={"LFSTUDIO_LOG_DIR": str(logs)})
    assert r.returncode == 0, r.stderr
    assert token not in r.stderr and "status page (read-only): http://127.0.0.1:" in r.stderr
    assert "with ?token= the --status-token given" in r.stderr
    logged = "".join(p.read_text(errors="replace") for p in logs.rglob("*") if p.is_file())
    assert "--status-token …" in logged and token not in logged
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", tmp_path / "day2",
                "--time-scale", "0", "--status-http", "127.0.0.1:0", "--status-token", "new",
                "--status-linger-s", "0", env={"LFSTUDIO_LOG_DIR": str(logs)})
    made = r.stderr.split("?token=", 1)[1].split()[0]
    assert r.returncode == 0 and len(made) >= 16 and r.stderr.count(made) == 1, r.stderr
    logged = "".join(p.read_text(errors="replace") for p in logs.rglob("*") if p.is_file())
    assert made not in logged
