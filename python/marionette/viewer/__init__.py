"""Browser 3D viewer of a run (issue #10), on meshcat.

| module | job |
|---|---|
| `scene.py` | `ViewerScene`: LCM messages -> meshcat commands (robot, objects, gripper/handle frames, footsteps, FSM text) |
| `node.py` | the viewer process (`marionette view`): meshcat server + LCM subscriptions |
| `replay.py` | `marionette replay LOG --view`: a recorded log played in the viewer, report re-plotted from the log |
| `screenshot.py` | headless Chromium screenshots of the page (tests, reports) |
| `cli.py` | `marionette view` |
"""
