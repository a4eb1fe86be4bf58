"""The window's side of unattended scans (:mod:`lfstudio.studio.unattended`, ``docs/unattended.md``):
the Settings dialog's "Unattended scans" group, what it stores (QSettings ``unattended/*``), the
options a scan started from the Scan panel gets, and the desktop notification (freedesktop
notifications over D-Bus) raised when the window is not in front.

Keys: ``unattended/notify`` (URLs, one a line), ``unattended/smtp``, ``unattended/smtp_sender``,
``unattended/smtp_password`` (kept in the settings file: readable by this user only),
``unattended/status`` (on/off), ``unattended/status_address``, ``unattended/status_token``,
``unattended/status_linger_s``, ``unattended/auto_resume``, ``unattended/on_finish``,
``unattended/on_finish_timeout_s``, ``unattended/desktop`` (on/off).

:class:`StatusPageLabel` is the Scan panel's line naming the status page's address while it serves
(during the scan and while it shows the final state after it): a click opens it, "Copy" copies it.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess

import time

from PySide6.QtCore import Qt, QTimer, QUrl
from PySide6.QtGui import QDesktopServices, QGuiApplication
from PySide6.QtWidgets import (QCheckBox, QDoubleSpinBox, QFormLayout, QGroupBox, QHBoxLayout, QLabel, QLineEdit,
                               QPlainTextEdit, QSpinBox, QWidget)

from lfstudio.errors import InputError
from lfstudio.gui.settings import read_float, read_int, settings
from lfstudio.gui.widgets import bounds_of, number_of
from lfstudio.scan.notify import SmtpServer, parse_target
from lfstudio.scan.status_http import LINGER_S, StatusServer, check_token, parse_address
from lfstudio.studio.scan_options import PARAMS as SCAN_PARAMS
from lfstudio.studio.unattended import CLI_NAMES, UnattendedOptions

log = logging.getLogger(__name__)

PREFIX = "unattended/"
DEFAULT_ADDRESS = "127.0.0.1:8765"
#: how the operator knows each option in the window (the start of a refusal's line)
NAMES = {name: f"Settings → Unattended scans → {SCAN_PARAMS[name].label}" for name in CLI_NAMES}


def _value(key: str, default: object = "") -> object:
    return settings().value(PREFIX + key, default)


def _bool(key: str, default: bool) -> bool:
    return str(_value(key, "true" if default else "false")).lower() in ("true", "1", "yes")


def load_options() -> UnattendedOptions:
    """The options a scan started in the window gets (as Settings stored them)."""
    auto = read_int(PREFIX + "auto_resume", 0)
    limit = read_float(PREFIX + "on_finish_timeout_s", 300.0)
    linger = read_float(PREFIX + "status_linger_s", LINGER_S)
    status = _bool("status", False)
    token = str(_value("status_token", "") or "")
    address = str(_value("status_address", DEFAULT_ADDRESS) or DEFAULT_ADDRESS)
    if status and not token:
        try:
            host, _ = parse_address(address)
            from lfstudio.scan.status_http import is_local

            token = "" if is_local(host) else "new"      # another computer's address: a token made per scan
        except InputError:
            pass
    return UnattendedOptions(notify=[u for u in str(_value("notify", "") or "").splitlines() if u.strip()],
                             smtp=str(_value("smtp", "") or ""), smtp_password=str(_value("smtp_password", "") or ""),
                             smtp_sender=str(_value("smtp_sender", "") or ""),
                             status_http=address if status else "", status_token=token if status else "",
                             auto_resume=auto, on_finish=str(_value("on_finish", "") or ""),
                             on_finish_timeout_s=limit, status_linger_s=linger, names=dict(NAMES))


def desktop_wanted() -> bool:
    return _bool("desktop", True)


class UnattendedBox(QGroupBox):
    """Settings → Unattended scans (see the module docstring); :meth:`check` before :meth:`store`."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__("Unattended scans", parent)
        self.setObjectName("unattendedBox")
        form = QFormLayout(self)
        self.notify = QPlainTextEdit(str(_value("notify", "") or ""))
        self.notify.setObjectName("notifyUrls")
        self.notify.setPlaceholderText("one URL a line: https://… (JSON), ntfy+https://ntfy.sh/TOPIC, "
                                       "slack+https://…, matrix+https://…, mailto:you@lab.example")
        self.notify.setToolTip("Told when a scan starts, pauses (why), resumes, fails, finishes or is aborted, "
                               "and of views the live check flags (docs/unattended.md)")
        self.notify.setFixedHeight(64)
        form.addRow(SCAN_PARAMS["notify"].label, self.notify)
        self.smtp = QLineEdit(str(_value("smtp", "") or ""))
        self.smtp.setObjectName("smtpServer")
        self.smtp.setPlaceholderText("smtp://you@mail.lab.example (for mailto:)")
        self.smtp.setToolTip("smtp:// (STARTTLS, 587), smtps:// (SSL, 465) or smtp+plain:// (a local relay)")
        self.smtp_password = QLineEdit(str(_value("smtp_password", "") or ""))
        self.smtp_password.setObjectName("smtpPassword")
        self.smtp_password.setEchoMode(QLineEdit.EchoMode.Password)
        self.smtp_password.setPlaceholderText("password")
        self.smtp_password.setToolTip("Stored in lfstudio's settings file (readable by you only); never logged")
        smtp_row = QHBoxLayout()
        smtp_row.addWidget(self.smtp, 2)
        smtp_row.addWidget(self.smtp_password, 1)
        form.addRow(SCAN_PARAMS["smtp"].label, smtp_row)
        self.status = QCheckBox("Serve a read-only status page")
        self.status.setObjectName("statusPage")
        self.status.setChecked(_bool("status", False))
        self.status.setToolTip("State, progress, ETA, the last thumbnails, live-check verdicts and the log for a "
                               "browser; /status.json for scripts. Nothing can be done through it")
        self.address = QLineEdit(str(_value("status_address", DEFAULT_ADDRESS) or DEFAULT_ADDRESS))
        self.address.setObjectName("statusAddress")
        self.address.setToolTip("[HOST:]PORT: 127.0.0.1 is this computer only; another address (0.0.0.0 for all) "
                                "needs a token")
        self.token = QLineEdit(str(_value("status_token", "") or ""))
        self.token.setObjectName("statusToken")
        self.token.setEchoMode(QLineEdit.EchoMode.Password)
        self.token.setPlaceholderText("token (optional)")
        self.token.setToolTip("Every request must carry it (?token=…) when the page listens for other computers; "
                              "empty: a new one is made for each scan and shown once in the Scan panel's log")
        self.linger = QDoubleSpinBox()
        self.linger.setObjectName("statusLinger")
        self.linger.setRange(*bounds_of(SCAN_PARAMS["status_linger_s"], "status_linger_s"))
        self.linger.setDecimals(0)
        self.linger.setPrefix("keep ")
        self.linger.setSuffix(" s after")
        self.linger.setSpecialValueText("closes with the scan")
        self.linger.setValue(read_float(PREFIX + "status_linger_s", LINGER_S))
        self.linger.setToolTip(SCAN_PARAMS["status_linger_s"].label + ": " + SCAN_PARAMS["status_linger_s"].tip)
        status_row = QHBoxLayout()
        status_row.addWidget(self.status)
        status_row.addWidget(self.address, 1)
        status_row.addWidget(self.token, 1)
        status_row.addWidget(self.linger)
        form.addRow("Status page", status_row)
        self.auto_resume = QSpinBox()
        self.auto_resume.setObjectName("autoResume")
        low, high = bounds_of(SCAN_PARAMS["auto_resume"], "auto_resume")   # as 'lfstudio scan --auto-resume' takes
        self.auto_resume.setRange(int(low), int(high))
        self.auto_resume.setValue(read_int(PREFIX + "auto_resume", 0))
        self.auto_resume.setSpecialValueText("never")
        self.auto_resume.setSuffix(" times")
        self.auto_resume.setToolTip("Resume by itself, at most this often, when a pause's cause clears (disk space "
                                    "freed, camera or controller back). STOP, limit switches, position errors and "
                                    "alarms that need homing always wait for you")
        self.desktop = QCheckBox("Desktop notifications when the window is not in front")
        self.desktop.setObjectName("desktopNotifications")
        self.desktop.setChecked(desktop_wanted())
        resume_row = QHBoxLayout()
        resume_row.addWidget(self.auto_resume)
        resume_row.addWidget(self.desktop, 1)
        form.addRow(SCAN_PARAMS["auto_resume"].label, resume_row)
        self.on_finish = QLineEdit(str(_value("on_finish", "") or ""))
        self.on_finish.setObjectName("onFinish")
        self.on_finish.setPlaceholderText("a shell command, e.g. lights and motors off")
        self.on_finish.setToolTip("Run once when the scan ends (finished, aborted or failed); $LFSTUDIO_SCAN_OUTCOME, "
                                  "$LFSTUDIO_DATASET, $LFSTUDIO_DONE, $LFSTUDIO_TOTAL tell it how. Its output goes to "
                                  "the Scan panel's log; a failure is notified")
        self.timeout = QDoubleSpinBox()
        self.timeout.setObjectName("onFinishTimeout")
        # the range and unit 'lfstudio scan --on-finish-timeout-s' takes
        limit = number_of(SCAN_PARAMS["on_finish_timeout_s"], "on_finish_timeout_s")
        self.timeout.setRange(*bounds_of(SCAN_PARAMS["on_finish_timeout_s"], "on_finish_timeout_s"))
        self.timeout.setDecimals(0)
        self.timeout.setSuffix(f" {limit.unit}")
        self.timeout.setValue(read_float(PREFIX + "on_finish_timeout_s", 300.0))
        self.timeout.setToolTip(f"The command is stopped after this long (valid: {limit.valid()})")
        finish_row = QHBoxLayout()
        finish_row.addWidget(self.on_finish, 1)
        finish_row.addWidget(self.timeout)
        form.addRow(SCAN_PARAMS["on_finish"].label, finish_row)

    def values(self) -> dict[str, object]:
        return {"notify": "\n".join(u.strip() for u in self.notify.toPlainText().splitlines() if u.strip()),
                "smtp": self.smtp.text().strip(), "smtp_password": self.smtp_password.text(),
                "status": self.status.isChecked(), "status_address": self.address.text().strip() or DEFAULT_ADDRESS,
                "status_token": self.token.text().strip(), "status_linger_s": self.linger.value(),
                "auto_resume": self.auto_resume.value(),
                "desktop": self.desktop.isChecked(), "on_finish": self.on_finish.text().strip(),
                "on_finish_timeout_s": self.timeout.value()}

    def check(self) -> str:
        """"" when the fields are well-formed, else one line naming the field (the port is only bound
        when a scan starts)."""
        v = self.values()
        try:
            targets = [parse_target(u, NAMES["notify"]) for u in str(v["notify"]).splitlines()]
            if v["smtp"]:
                SmtpServer.parse(str(v["smtp"]), option=NAMES["smtp"])
            elif any(t.shape == "mail" for t in targets):
                raise InputError(NAMES["notify"], "a mailto: target needs an SMTP server", "fill in SMTP server")
            if v["status"]:
                host, _ = parse_address(str(v["status_address"]), NAMES["status_http"])
                check_token(host, str(v["status_token"]) or "new", NAMES["status_http"], NAMES["status_token"])
        except InputError as exc:
            return str(exc)
        return ""

    def store(self) -> None:
        s = settings()
        for key, value in self.values().items():
            s.setValue(PREFIX + key, value)
        s.sync()
        try:
            os.chmod(s.fileName(), 0o600)         # it may hold the SMTP password and the token
        except OSError:
            pass
        log.info("unattended-scan settings changed (notify: %d URL(s), status page %s, auto-resume %d)",
                 len([u for u in str(self.values()["notify"]).splitlines() if u]),
                 "on" if self.status.isChecked() else "off", self.auto_resume.value())


class StatusPageLabel(QLabel):
    """The status page's address in the Scan panel: shown while the page serves (see the module
    docstring); hidden otherwise. The link opens the page (with its token); "Copy" copies that address."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("statusPageAddress")
        self.setTextFormat(Qt.TextFormat.RichText)
        self.setTextInteractionFlags(Qt.TextInteractionFlag.TextBrowserInteraction)
        self.setOpenExternalLinks(False)
        self.setWordWrap(True)
        self.linkActivated.connect(self._activated)
        self.server: StatusServer | None = None
        self._hide_timer = QTimer(self)
        self._hide_timer.setSingleShot(True)
        self._hide_timer.timeout.connect(self.clear_page)
        self.hide()

    @property
    def address(self) -> str:
        """The address to open (with the token when the page needs one); "" when none is shown."""
        return self.server.url_with_token() if self.server is not None else ""

    def show_page(self, server: StatusServer, until: float | None = None) -> None:
        """Name ``server``'s page: serving the scan, or (``until``: time.time()) its final state until then."""
        self.server = server
        when = (f" · the final state, until {time.strftime('%H:%M', time.localtime(until))}" if until is not None
                else "")
        self.setText(f"Status page: <a href='open'>{server.url}</a> · <a href='copy'>Copy</a>{when}")
        self.setToolTip("Opens in your browser; Copy puts the address" + (" with its token" if server.token else "")
                        + " on the clipboard (File → Settings → Unattended scans sets it up)")
        self.show()
        self._hide_timer.stop()
        if until is not None:
            self._hide_timer.start(max(0, int((until - time.time()) * 1000)) + 500)

    def clear_page(self) -> None:
        self.server = None
        self.setText("")
        self.hide()

    def _activated(self, link: str) -> None:
        if not self.address:
            return
        if link == "copy":
            QGuiApplication.clipboard().setText(self.address)
        else:
            QDesktopServices.openUrl(QUrl(self.address))


# -- desktop notifications ---------------------------------------------------------------------------
def desktop_notify(title: str, body: str, *, urgent: bool = False) -> bool:
    """Raise a freedesktop notification (``org.freedesktop.Notifications.Notify`` on the session D-Bus)
    through GLib's ``gdbus`` tool, which types the call's arguments exactly as the specification
    wants them (``susssasa{sv}i``; PySide6's QtDBus cannot make the ``u``). Not waited for. False when
    there is no session bus or no ``gdbus`` (then nothing happens)."""
    gdbus = shutil.which("gdbus")
    if gdbus is None or not os.environ.get("DBUS_SESSION_BUS_ADDRESS"):
        return False

    def text(value: str) -> str:               # a GVariant string literal
        return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"
    hints = "{'urgency': <byte %d>, 'desktop-entry': <'lfstudio'>}" % (2 if urgent else 1)
    try:
        subprocess.Popen([gdbus, "call", "--session", "--dest", "org.freedesktop.Notifications",
                          "--object-path", "/org/freedesktop/Notifications",
                          "--method", "org.freedesktop.Notifications.Notify", "--", "'lfstudio'", "uint32 0",
                          "'lfstudio'", text(title), text(body), "@as []", hints, "int32 -1"],
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    except OSError as exc:
        log.info("desktop notification not raised: %s", exc)
        return False
    return True
