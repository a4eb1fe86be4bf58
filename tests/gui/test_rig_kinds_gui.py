"""The Rig panel lists the rig kinds of plugins (entry points lfstudio.rigs) and connects one by its word
(offscreen Qt, real loop and worker)."""

from __future__ import annotations

from lfstudio.gui.panels.rig import RigPanel
from lfstudio.gui.state import AppState
from lfstudio.rig.motion import RigState
from lfstudio.studio.kinds import RigKind, register_rig, unregister


def test_a_plugin_rig_is_listed_and_connects_by_its_word(qtbot):
    from lfstudio.studio.simulated import InstantRig

    opened: list[str] = []

    def open_rig(argument, ctx):
        opened.append(argument)
        return InstantRig(ctx.config)

    register_rig(RigKind("benchrig", open_rig, "Bench rig", argument="NAME", origin="plugin bench 1.0 (m:f)"))
    try:
        state = AppState(simulated=False)
        panel = RigPanel(state)
        qtbot.addWidget(panel)
        index = panel.port_combo.findData("benchrig:")
        assert index >= 0 and "plugin bench 1.0 (m:f)" in panel.port_combo.itemData(index, 3)   # its tooltip
        panel.port_combo.setEditText("benchrig:left")
        assert panel.chosen_port() == "benchrig:left"
        panel.connect_rig()
        qtbot.waitUntil(lambda: panel.last_status is not None and panel.last_status.state is RigState.IDLE,
                        timeout=20000)
        assert opened == ["left"]
        assert state.devices["rig_link"].record()["kind"] == "benchrig"
        panel.shutdown()
    finally:
        unregister("benchrig")


def test_the_rig_panel_builds_the_ports_kind_options_form_and_connects_with_them(qtbot):
    """The Options form follows the port's kind (its described options); a bad field is named by its label
    and nothing connects; good values reach the driver."""
    state = AppState(simulated=True)
    panel = RigPanel(state)
    qtbot.addWidget(panel)
    panel.sim_time_scale = 0.0
    try:
        assert panel.chosen_port() == "sim" and panel.options_button.isEnabled()
        assert panel.options_button.text() == "Options: Simulated GRBL"
        panel.options_button.setChecked(True)
        form = panel.options_stack.currentWidget()
        assert set(form.fields) >= {"baudrate", "timeout_s", "poll_hz", "stall_s"} and form.argument is None
        form.fields["poll_hz"].setText("0")
        panel.connect_rig()
        assert panel.device is None and "Status polls" in panel.message_label.text(), panel.message_label.text()
        form.fields["poll_hz"].setText("40")
        panel.connect_rig()
        qtbot.waitUntil(lambda: panel.last_status is not None and panel.last_status.state is not RigState.DISCONNECTED,
                        timeout=20000)
        assert panel.link.controller.poll_period_s == 1 / 40
        assert not panel.options_stack.isEnabled()               # fixed while connected
        panel.disconnect_rig()
        panel.port_combo.setEditText("dryve:10.0.0.1,10.0.0.2")
        assert panel.options_button.text() == "Options: CiA 402 drives over Modbus TCP (igus dryve D1)"
        drives = panel.options_stack.currentWidget()
        assert "accept_reference" in drives.flags and drives.options() == {}       # a check box, unticked
        drives.flags["accept_reference"].setChecked(True)
        assert drives.options() == {"accept_reference": True}
        panel.port_combo.setEditText("instant")
        assert not panel.options_button.isEnabled() and not panel.options_stack.isVisible()
        assert panel.port_combo.findData("dryve:") >= 0 and panel.port_combo.findData("canopen:") >= 0
    finally:
        panel.shutdown()


def test_keep_drive_reference_holds_for_one_connect_and_is_never_remembered(qtbot):
    """Keeping the drives' reference is an act on one connection (#38): the Options box is unticked once
    a Connect used it, and a form made later (the next day's window) shows it unticked; the other fields
    are remembered."""
    from lfstudio.gui.kind_form import KindForm
    from lfstudio.studio.kinds import rig_kind

    kind = rig_kind("dryve")
    assert kind is not None
    form = KindForm(kind, argument=False)
    qtbot.addWidget(form)
    form.flags["accept_reference"].setChecked(True)
    form.fields["poll_hz"].setText("40")
    assert form.options() == {"accept_reference": True, "poll_hz": 40.0}
    form.save()
    assert not form.flags["accept_reference"].isChecked() and form.options() == {"poll_hz": 40.0}
    later = KindForm(kind, argument=False)
    qtbot.addWidget(later)
    assert not later.flags["accept_reference"].isChecked()
    assert later.options() == {"poll_hz": 40.0}


def _next_tab(widget):
    """Where Tab goes from ``widget``: the next shown, enabled widget in the focus chain that takes Tab."""
    from PySide6.QtCore import Qt

    w = widget.nextInFocusChain()
    while w is not widget:
        if w.isVisible() and w.isEnabled() and w.focusPolicy() & Qt.FocusPolicy.TabFocus:
            return w
        w = w.nextInFocusChain()
    return None


def test_tab_goes_from_options_into_its_form_and_the_form_takes_its_own_height(qtbot):
    """A kind's Options form is made when its port is first chosen, after the rest of the panel: its
    fields were last in the tab order (Options -> Go to x, y, Go -> the fields). Tab now goes from
    Options through the form, then on to Position. The Options box takes the shown form's height."""
    state = AppState(simulated=True)
    panel = RigPanel(state)
    qtbot.addWidget(panel)
    panel.resize(440, 700)
    panel.show()
    qtbot.waitExposed(panel)
    try:
        panel.options_button.setChecked(True)
        for port in ("sim", "dryve:10.0.0.1,10.0.0.2", "sim"):
            panel.port_combo.setEditText(port)
            form = panel.options_stack.currentWidget()
            order, w = [], panel.options_button
            for _ in range(len(form.fields) + len(form.flags)):
                w = _next_tab(w)
                order.append(w)
            assert order == [*form.fields.values(), *form.flags.values()], port
            after = _next_tab(order[-1])
            assert after is not None and not form.isAncestorOf(after), port
            width = panel.options_stack.width()
            assert panel.options_stack.heightForWidth(width) == form.heightForWidth(width), port
    finally:
        panel.shutdown()


def test_a_kind_picked_from_the_port_list_shows_its_options_before_its_addresses(qtbot):
    """'dryve:' and 'canopen:' as the Port list offers them (the addresses not typed yet) said 'Options:
    none for this port', greyed out, until an address was typed."""
    state = AppState(simulated=True)
    panel = RigPanel(state)
    qtbot.addWidget(panel)
    try:
        for word, label in (("dryve:", "CiA 402 drives over Modbus TCP (igus dryve D1)"), ("canopen:", None)):
            panel.port_combo.setCurrentIndex(panel.port_combo.findData(word))
            assert panel.chosen_port() == word
            assert panel.options_button.isEnabled(), word
            assert "none for this port" not in panel.options_button.text(), word
            if label:
                assert panel.options_button.text() == f"Options: {label}"
        panel.port_combo.setEditText("instant")
        assert not panel.options_button.isEnabled()
    finally:
        panel.shutdown()


def test_every_kinds_description_starts_as_a_sentence(qtbot):
    """A kind's help is written for the command line's lists ('the GRBL controller simulator on a
    pseudo-terminal …'); at the top of its Options form or Camera page it is a sentence of its own."""
    from lfstudio.gui.kind_form import KindForm
    from lfstudio.studio.kinds import camera_kinds, rig_kinds

    kinds = [k for k in (*rig_kinds().values(), *camera_kinds().values()) if k.help]
    assert any(k.help[0].islower() for k in kinds)            # there are such helps
    for kind in kinds:
        form = KindForm(kind, argument=False)
        qtbot.addWidget(form)
        first = form.info.text()[:1]
        assert not first.isalpha() or first.isupper(), (kind.name, form.info.text())
