"""The operator's 3-D scene, drawn with viser (UWSim's role in the published system).

- `app.ConsoleScene(operator, host="127.0.0.1", port=8080)`: `.start()`, `.stop()`, `.url`.
- `frames`: how NED, the vehicle's body, its camera and images map into viser's
  world (ENU, z up).
- `panel`: the control panel (arming, mode, velocity, target, image settings,
  link health, live plots).
- `roi`: mouse rectangles on the picture <-> the IMAGE order's pixel ROI.
- `rov_model`: the BlueROV-like mesh (`python -m console.scene.rov_model` writes
  `assets/rov.glb`).
"""

from .app import ConsoleScene

__all__ = ["ConsoleScene"]
