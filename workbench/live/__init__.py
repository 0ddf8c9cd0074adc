"""The live view: a running rig served over the Foxglove WebSocket protocol (:mod:`workbench.live.view`)."""
