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
