"""A notification endpoint that redirects (#42 item 7) and SMTP without encryption (item 8): the URL's
credentials never go where a redirect points, and a notice that was not delivered is logged as such,
with the reason. Real HTTP servers on 127.0.0.1."""

from __future__ import annotations

import logging
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from lfstudio.errors import InputError
from lfstudio.scan.notify import Notifier, SmtpServer


class Recorder:
    """Answers every request (any method) with ``status`` (and ``location``), recording each."""

    def __init__(self, status: int = 200, location: str = ""):
        self.requests: list[dict] = []
        recorder = self

        class Handler(BaseHTTPRequestHandler):
            def _any(self):
                length = int(self.headers.get("Content-Length", 0) or 0)
                body = self.rfile.read(length) if length else b""
                recorder.requests.append({"method": self.command, "path": self.path, "headers": dict(self.headers),
                                          "body": body})
                self.send_response(status)
                if location:
                    self.send_header("Location", location)
                self.send_header("Content-Length", "0")
                self.end_headers()

            do_GET = do_POST = do_PUT = do_HEAD = _any  # noqa: N815

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.mark.parametrize("code", [301, 302, 303, 307, 308])
def test_a_redirect_is_not_followed_and_the_notice_is_logged_as_not_delivered(code, caplog):
    elsewhere = Recorder(200)
    hook = Recorder(code, f"http://127.0.0.1:{elsewhere.port}/collect")
    deliveries = []
    try:
        notifier = Notifier([f"http://alice:pa55word-x@127.0.0.1:{hook.port}/hook/S3CRETPATH"], dataset="day1",
                            retries=2, backoff_s=0.01)
        notifier.subscribe(deliveries.append)
        with caplog.at_level(logging.INFO, logger="lfstudio.scan.notify"):
            notifier.notify("started", "Running")
            assert notifier.close(30)
    finally:
        hook.close()
        elsewhere.close()
    assert elsewhere.requests == []                       # nothing (no credentials, no GET) went there
    assert len(hook.requests) == 1 and hook.requests[0]["method"] == "POST"   # not retried: it cannot succeed
    (delivery,) = deliveries
    assert not delivery.ok and f"answered {code}" in delivery.error and "not followed" in delivery.error
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "notification started" in warnings[0] and "not delivered" in warnings[0]
    assert f"a redirect to http://127.0.0.1:{elsewhere.port}/…" in warnings[0]
    assert "pa55word" not in caplog.text and "S3CRETPATH" not in caplog.text


def test_smtp_plain_with_a_user_is_refused_unless_on_this_computer():
    with pytest.raises(InputError) as err:
        SmtpServer.parse("smtp+plain://alice@mail.lab.example")
    assert str(err.value).startswith("--smtp: smtp+plain:// would send alice's password unencrypted to "
                                     "mail.lab.example")
    assert "smtps://" in str(err.value)
    assert SmtpServer.parse("smtp+plain://alice@127.0.0.1:2525").security == "none"     # a local relay
    assert SmtpServer.parse("smtp+plain://relay.lab.example").user == ""                 # no password sent
