"""Browser 3D viewer of a run, on meshcat.

| module | job |
|---|---|
| `scene.py` | `ViewerScene`: LCM messages -> meshcat (robot, objects, frames, steps, FSM) |
| `node.py` | the viewer process (`marionette view`): meshcat server + LCM subscriptions |
| `replay.py` | `marionette replay LOG --view`: a recorded log in the viewer, report re-plotted |
| `screenshot.py` | headless Chromium screenshots of the page (tests, reports) |
| `cli.py` | `marionette view` |
"""
