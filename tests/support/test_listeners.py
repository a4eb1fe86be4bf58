"""The one subscribe-and-notify mechanism (lfstudio/support/listeners.py)."""

from __future__ import annotations

import logging

from lfstudio.support.listeners import Listeners


def test_a_broken_listener_is_logged_and_the_others_still_hear(caplog):
    heard: list[int] = []
    listeners: Listeners[int] = Listeners("test listener", logging.getLogger("lfstudio.test"))

    def broken(value: int) -> None:
        raise RuntimeError("boom")

    listeners.add(broken)
    listeners.add(heard.append)
    with caplog.at_level(logging.ERROR, logger="lfstudio.test"):
        listeners.notify(7)
    assert heard == [7]
    assert "test listener failed" in caplog.text and "boom" in caplog.text


def test_removing_stops_a_listener_also_from_inside_a_notification():
    heard: list[str] = []
    listeners: Listeners[str] = Listeners("test listener", logging.getLogger("lfstudio.test"))

    def once(value: str) -> None:
        heard.append("once:" + value)
        remove_once()

    remove_once = listeners.add(once)
    remove_all = listeners.add(lambda v: heard.append("all:" + v))
    listeners.notify("a")
    listeners.notify("b")
    remove_all()
    remove_all()                       # removing twice is harmless
    listeners.notify("c")
    assert heard == ["once:a", "all:a", "all:b"]
