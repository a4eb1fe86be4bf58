"""No secret in clear anywhere (#42 item 6): a real ``lfstudio scan`` given a --notify URL with a user,
password and webhook path, a --status-token and an SMTP password; while it runs a second command is
refused on its dataset; then Ctrl+C. Every file under the dataset, the log folder and the runtime
(lock) folder, the lock files as they were while the scan held them, and the captured output of both
commands are searched for the secret values. Real processes and sockets on 127.0.0.1."""

from __future__ import annotations

import json
import shlex
import signal
import subprocess
import sys
import time

from tests.conftest import REPO_ROOT
from tests.scan.receivers import DeadEndpoint, Receiver
from tests.scankill import journal_lines, lfstudio_env

PASSWORD = "Pa55-word-in-url"
WEBHOOK = "W3bhookP4thSecret"
TOKEN = "StatusT0ken-given-by-me"
SMTP_PASSWORD = "SmtpPa55-from-env"
SECRETS = (PASSWORD, WEBHOOK, TOKEN, SMTP_PASSWORD)


def everything_under(*folders) -> dict[str, bytes]:
    return {str(p): p.read_bytes() for folder in folders for p in folder.rglob("*") if p.is_file()}


def test_a_scans_secrets_reach_no_file_log_lock_or_message(tmp_path):
    out, logs, runtime = tmp_path / "day1", tmp_path / "logs", tmp_path / "run"
    receiver, smtp = Receiver(), DeadEndpoint()
    env = {**lfstudio_env(), "LFSTUDIO_LOG_DIR": str(logs), "LFSTUDIO_RUNTIME_DIR": str(runtime),
           "LFSTUDIO_SMTP_PASSWORD": SMTP_PASSWORD}
    args = ["--port", "sim", "--camera", "sim", "--grid", "8x3", "--time-scale", "0.3", "--sim-width-px", "96",
            "--notify", f"http://alice:{PASSWORD}@127.0.0.1:{receiver.port}/hooks/{WEBHOOK}?key={WEBHOOK}",
            "--notify", "mailto:me@lab.example", "--smtp", f"smtp://me@127.0.0.1:{smtp.port}",
            "--status-http", "127.0.0.1:0", "--status-token", TOKEN, "--status-linger-s", "0"]
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "scan", *args, "--out", str(out)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT)
    try:
        while proc.poll() is None and journal_lines(out) < 2:
            time.sleep(0.01)        # polling the journal the scan writes, not synchronising on a duration
        assert proc.poll() is None, proc.communicate()
        held = everything_under(out, runtime)              # the lock files while the scan holds them
        assert json.loads(held[str(out / "dataset.lock")])["command"].startswith("lfstudio scan --port sim")
        assert any("port-" in name and b'"command"' in data for name, data in held.items())
        second = subprocess.run([sys.executable, "-m", "lfstudio", "scan", "--resume", "--out", str(out)], env=env,
                                capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
        assert second.returncode != 0 and "is in use by lfstudio scan" in second.stderr, second.stderr
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        receiver.close()
        smtp.close()
    assert proc.returncode == 130, stderr
    resume = next(line for line in stderr.splitlines() if line.startswith("  lfstudio scan --resume")).strip()
    assert resume.startswith("lfstudio scan --resume") and "--status-token '…'" in resume
    assert f"--notify 'http://127.0.0.1:{receiver.port}/…'" in resume and "give the …-shortened secrets" in resume
    assert shlex.split(resume)                                 # still a command line a shell reads
    assert receiver.posts and receiver.posts[0]["headers"]["Authorization"].startswith("Basic ")   # it was used
    texts = {"scan stdout": stdout, "scan stderr": stderr, "second stdout": second.stdout,
             "second stderr": second.stderr}
    files = {**everything_under(out, logs, runtime), **{f"{k} (while held)": v for k, v in held.items()}}
    assert any("lfstudio.log" in name for name in files)
    for secret in SECRETS:
        for name, text in texts.items():
            assert secret not in text, (secret, name)
        for name, data in files.items():
            assert secret.encode() not in data, (secret, name)


def test_after_the_scan_the_cli_keeps_the_page_with_its_final_state_until_ctrl_c(tmp_path):
    """--status-linger-s: the page answers after the scan (outcome finished) until its time or Ctrl+C."""
    import urllib.request

    out = tmp_path / "day1"
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "scan", "--port", "instant", "--camera", "instant",
                             "--grid", "3x2", "--time-scale", "0", "--out", str(out), "--status-http", "127.0.0.1:0",
                             "--status-linger-s", "3600"], env=lfstudio_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT)
    lines = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line)
            if "shows the final state until" in line:
                break
        url = next(line.split("status page (read-only): ", 1)[1].split()[0] for line in lines
                   if "status page (read-only)" in line)
        with urllib.request.urlopen(url + "status.json", timeout=30) as reply:
            doc = json.loads(reply.read())
        assert (doc["state"], doc["outcome"], doc["done"], doc["total"]) == ("finished", "finished", 6, 6)
        assert doc["ended"] and doc["serving_until"]
        assert proc.poll() is None                     # still serving
        proc.send_signal(signal.SIGINT)
        rest = proc.communicate(timeout=60)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0 and "Traceback" not in rest, rest
