"""Secrets redacted once, where they are read (lfstudio/support/secrets.py): a Secret shows its
redacted form everywhere but reveal(); the lock files' command line is the recorded, redacted one; the
log handlers scrub any known secret value."""

from __future__ import annotations

import json
import logging
import pickle

from lfstudio.support import secrets
from lfstudio.support.locks import dataset_lock
from lfstudio.support.secrets import ScrubFilter, Secret


def test_a_secret_shows_its_redacted_form_everywhere_but_reveal():
    s = Secret("https://u:pw-123456@h.example/hook", "https://h.example/…")
    assert (str(s), repr(s), f"{s}", f"[{s:>22}]") == ("https://h.example/…", "Secret('https://h.example/…')",
                                                        "https://h.example/…", "[   https://h.example/…]")
    assert s.reveal() == "https://u:pw-123456@h.example/hook" and bool(s) and not Secret("")
    assert pickle.loads(pickle.dumps(s)) == s and "pw-123456" not in repr([s, {"k": s}])


def test_the_lock_file_holds_the_recorded_command_line(tmp_path, monkeypatch):
    monkeypatch.setattr(secrets, "_command_line", None)
    monkeypatch.setattr("sys.argv", ["lfstudio", "scan", "--status-token", "tok-SECRET-123456"])
    Secret("tok-SECRET-123456")
    with dataset_lock(tmp_path, "scanning"):       # nothing recorded: sys.argv without known secrets
        assert "tok-SECRET-123456" not in (tmp_path / "dataset.lock").read_text()
    secrets.set_command_line(["lfstudio", "scan", "--status-token", "…"])
    with dataset_lock(tmp_path, "scanning"):
        assert json.loads((tmp_path / "dataset.lock").read_text())["command"] == "lfstudio scan --status-token …"


def test_the_log_filter_scrubs_known_secrets():
    Secret("pw-SCRUBBED-987")
    record = logging.LogRecord("x", logging.INFO, __file__, 1, "login with %s failed", ("pw-SCRUBBED-987",), None)
    assert ScrubFilter().filter(record) and record.getMessage() == "login with … failed"


def test_an_abbreviated_secret_option_is_masked_too(tmp_path, monkeypatch):
    """argparse takes --status-tok for --status-token: its value is the token all the same, and it
    reached the lock files (the recorded command line was not scrubbed)."""
    from lfstudio.cli import build_parser, loggable

    argv = ["scan", "--port", "sim", "--status-tok", "tok-ABBREV-424242", "--status-t=tok-ABBREV-434343"]
    args = build_parser().parse_args([*argv, "--out", str(tmp_path / "d")])
    assert isinstance(args.status_token, Secret) and args.status_token.reveal() == "tok-ABBREV-434343"
    shown = loggable(argv)
    assert shown == ["scan", "--port", "sim", "--status-tok", "…", "--status-t=…"]
    monkeypatch.setattr(secrets, "_command_line", None)
    secrets.set_command_line(["lfstudio", *argv])        # recorded as given: the lock file scrubs known secrets
    with dataset_lock(tmp_path, "scanning"):
        text = (tmp_path / "dataset.lock").read_text()
    assert "tok-ABBREV-424242" not in text and "tok-ABBREV-434343" not in text and "--status-tok" in text
