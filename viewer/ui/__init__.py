"""The imgui interface of ``phyir-view`` (:class:`viewer.ui.gui.Gui`): menu bar, side panel, status
bar, input handling and the inserted objects' panel, one module each."""
