"""The viser control panel: every button, slider, readout and plot of the console.

Goals
- Everything the pilot does without the mouse in the scene: arm/disarm, mode,
  velocity by sliders and by keys, the supervised Send/Stop, the image settings;
  and everything he must watch: the vehicle's state, the picture and its
  reception progress, the link's health, and two live plots after the paper's
  figures (commanded against received velocity, Fig. 5; a time-lapse of the link's
  traffic and losses, Fig. 4).
- Controls only call the operator (or the scene for what the scene owns); the
  readouts are refreshed by the scene's update thread at 2 Hz, in place.

Plan: one `_build_*` per folder, one `_refresh_*` per readout; callbacks are
one-liners into plain methods.  Keys are viser commands (hotkeys): each press
nudges one axis of the velocity wish by `KEY_STEP`; X zeroes it.  viser reports
key presses, not releases, so keys step rather than hold.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np
from viser import uplot

from rovlink.link.messages import MAX_BUDGET

if TYPE_CHECKING:  # the scene imports the panel; only the type goes the other way
    from .app import ConsoleScene

MODES = ("MANUAL", "STABILIZE", "DEPTH_HOLD", "POS_HOLD", "GUIDED", "SURFACE")
AXES = ("vx", "vy", "vz", "vyaw")
AXIS_LABELS = {"vx": "Surge (forward +)", "vy": "Sway (right +)", "vz": "Heave (down +)", "vyaw": "Yaw (clockwise +)"}
KEY_STEP = 0.1
# key -> (axis, step); z is down and yaw clockwise, as in the protocol's wish.
KEYS = {"W": ("vx", KEY_STEP), "S": ("vx", -KEY_STEP), "D": ("vy", KEY_STEP), "A": ("vy", -KEY_STEP),
        "F": ("vz", KEY_STEP), "R": ("vz", -KEY_STEP), "E": ("vyaw", KEY_STEP), "Q": ("vyaw", -KEY_STEP)}
PLOT_SPAN_S = 30.0
VELOCITY_STEP_S = 0.1
LINK_BIN_S = 0.5


def step_values(samples, t_grid: np.ndarray, column: int) -> np.ndarray:
    """A value held from each sample (t, ...) until the next, read on `t_grid`;
    zero before the first."""
    if not samples:
        return np.zeros_like(t_grid)
    a = np.asarray(samples, float)
    idx = np.searchsorted(a[:, 0], t_grid, side="right") - 1
    return np.where(idx >= 0, a[np.maximum(idx, 0), column], 0.0)


def link_bins(events, t_end: float, span_s: float = PLOT_SPAN_S, bin_s: float = LINK_BIN_S):
    """Bytes/s sent and received, and replies lost, in bins over the last `span_s`."""
    edges = np.arange(t_end - span_s, t_end + 1e-9, bin_s)
    centres = edges[:-1] + bin_s / 2
    out = {k: np.zeros(len(centres)) for k in ("tx", "rx", "lost")}
    for t, kind, n in events:
        if kind in out and edges[0] <= t < edges[-1]:
            i = int((t - edges[0]) // bin_s)
            out[kind][i] += 1 if kind == "lost" else n / bin_s
    return centres - t_end, out


class ControlPanel:
    def __init__(self, gui, operator, scene: "ConsoleScene") -> None:
        self.gui = gui
        self.operator = operator
        self.scene = scene
        # A refused viewer's slider or dropdown goes back to the last value
        # accepted; the assignment calls our callbacks (client None) in this
        # thread, which must not order again: `_quiet` tells them.
        self._quiet = threading.local()
        self._accepted: dict[int, object] = {}  # id(handle) -> its last accepted value
        self._build_vehicle()
        self._build_velocity()
        self._build_target()
        self._build_image()
        self._build_link()
        self._build_plots()

    # ------------------------------------------------------------------
    # Vehicle: arm, mode, state
    # ------------------------------------------------------------------

    def _build_vehicle(self) -> None:
        with self.gui.add_folder("Vehicle"):
            self.vehicle_md = self.gui.add_markdown("*waiting for the first odometry*")
            self.arming = self.gui.add_button_group("Arming", ("Arm", "Disarm"))
            self.mode = self.gui.add_dropdown("Request mode", MODES, initial_value="MANUAL")

        @self.arming.on_click
        def _(event) -> None:
            if self.scene.permit(event.client):
                self.operator.arm(event.target.value == "Arm")

        self._guard(self.mode, lambda: self.operator.set_mode(self.mode.value))

    def _guard(self, handle, accepted=None) -> None:
        """A shared input: a change from a viewer who may not order goes
        back to the last accepted value; an accepted one calls `accepted`."""
        self._accepted[id(handle)] = handle.value

        def on_update(event) -> None:
            if getattr(self._quiet, "on", False):
                return
            if not self.scene.permit(event.client):
                self._quiet.on = True
                try:
                    handle.value = self._accepted[id(handle)]
                finally:
                    self._quiet.on = False
                return
            self._accepted[id(handle)] = handle.value
            if accepted is not None:
                accepted()

        handle.on_update(on_update)

    def _refresh_vehicle(self) -> None:
        state = self.operator.pose_state()
        pose = state.get("received")
        if pose is None:
            return
        flags = " · ".join(f for f, on in (("**FAILSAFE**", state.get("failsafe")),
                                             ("autopilot lost", not state.get("autopilot"))) if on)
        self.vehicle_md.content = (
            f"{'**ARMED**' if state.get('armed') else 'disarmed'} · {state.get('mode')}"
            f"{' · ' + flags if flags else ''}  \n"
            f"N {pose['x_m']:+.2f} m, E {pose['y_m']:+.2f} m, depth {pose['z_m']:.2f} m, "
            f"heading {pose['yaw_deg'] % 360:.0f}°")

    # ------------------------------------------------------------------
    # Velocity: sliders and keys
    # ------------------------------------------------------------------

    def _build_velocity(self) -> None:
        with self.gui.add_folder("Velocity"):
            self.sliders = {a: self.gui.add_slider(AXIS_LABELS[a], min=-1.0, max=1.0, step=0.05, initial_value=0.0)
                            for a in AXES}
            self.zero_button = self.gui.add_button("Zero velocity (X)")
            self.gui.add_markdown("Keys: W/S surge, A/D sway, R/F up/down, Q/E yaw, "
                                  f"{KEY_STEP:g} per press; X zero.")
        for slider in self.sliders.values():
            self._guard(slider, self.send_velocity)
        self.zero_button.on_click(lambda event: self.scene.permit(event.client) and self.zero_velocity())
        for key, (axis, step) in KEYS.items():
            command = self.gui.add_command(f"Velocity {axis} {step:+g}", hotkey=key)
            command.on_trigger(lambda event, axis=axis, step=step:
                               self.scene.permit(event.client) and self.nudge_velocity(axis, step))
        self.gui.add_command("Zero velocity", hotkey="X").on_trigger(
            lambda event: self.scene.permit(event.client) and self.zero_velocity())

    def velocity_wish(self) -> tuple[float, float, float, float]:
        return tuple(float(self.sliders[a].value) for a in AXES)  # type: ignore[return-value]

    def send_velocity(self) -> None:
        self.operator.set_velocity(*self.velocity_wish())

    def nudge_velocity(self, axis: str, step: float) -> None:
        slider = self.sliders[axis]
        slider.value = round(min(1.0, max(-1.0, slider.value + step)), 2)  # its callback sends

    def zero_velocity(self) -> None:
        self.zero_velocity_controls()
        self.send_velocity()

    def zero_velocity_controls(self) -> None:
        for slider in self.sliders.values():
            slider.value = 0.0

    # ------------------------------------------------------------------
    # Supervised control
    # ------------------------------------------------------------------

    def _build_target(self) -> None:
        with self.gui.add_folder("Target"):
            self.target_md = self.gui.add_markdown("Move the gizmo to set a target; the path is previewed, "
                                                   "nothing is sent before **Send**.")
            self.send_button = self.gui.add_button("Send", color="green", disabled=True)
            self.stop_button = self.gui.add_button("Stop", color="red")
            self.reset_button = self.gui.add_button("Reset target")
        self.send_button.on_click(lambda event: self.scene.permit(event.client) and self.scene.send_target())
        self.stop_button.on_click(lambda _event: self.scene.stop_vehicle())  # anyone may stop
        self.reset_button.on_click(lambda event: self.scene.permit(event.client) and self.scene.reset_target())

    def show_target(self, target, order_id) -> None:
        if target is None:
            self.target_md.content = "No target. Move the gizmo to set one."
            self.send_button.disabled = True
            return
        x, y, z, yaw = target
        sent = f"sent as order {order_id}" if order_id is not None else "**not sent**"
        self.target_md.content = f"Target N {x:+.2f} E {y:+.2f} depth {z:.2f} m, heading {yaw % 360:.0f}° — {sent}"
        self.send_button.disabled = order_id is not None

    # ------------------------------------------------------------------
    # Image: picture, progress, settings
    # ------------------------------------------------------------------

    def _build_image(self) -> None:
        settings = self.operator.requested_settings
        with self.gui.add_folder("Image"):
            w, h = self.scene.image_px
            self.picture = self.gui.add_image(np.full((h, w, 3), 30, np.uint8), label="Latest image",
                                              format="jpeg", jpeg_quality=90)
            self.progress = self.gui.add_progress_bar(0.0, color="cyan")
            self.image_md = self.gui.add_markdown("*no image yet*")
            self.budget = self.gui.add_slider("Budget (bytes)", min=200, max=MAX_BUDGET, step=100,
                                              initial_value=int(min(MAX_BUDGET, max(200, settings.budget_bytes))))
            self.shift_slider = self.gui.add_slider("ROI shift", min=0, max=15, step=1, initial_value=settings.shift or 4)
            self.mono = self.gui.add_checkbox("Mono", initial_value=settings.mono)
            self.apply_button = self.gui.add_button("Apply image settings")
            self.clear_roi_button = self.gui.add_button("Clear ROI")
            self.next_button = self.gui.add_button("Next image")
            self.gui.add_markdown("Drag a rectangle on the picture in the scene to set the ROI.")
        # The settings are shared by every viewer and go out with the next
        # Apply or ROI: a viewer who may not order may not change them either.
        for handle in (self.budget, self.shift_slider, self.mono):
            self._guard(handle)
        self.apply_button.on_click(lambda event: self.scene.permit(event.client) and self.apply_image_settings())
        self.clear_roi_button.on_click(lambda event: self.scene.permit(event.client) and self.scene.clear_roi())
        self.next_button.on_click(lambda event: self.scene.permit(event.client) and self.operator.next_image())

    @property
    def shift(self) -> int:
        return int(self.shift_slider.value)

    def apply_image_settings(self) -> int:
        roi = self.operator.requested_settings.roi  # keep the ROI the pilot drew
        return self.operator.set_image_settings(roi=roi, shift=self.shift if roi else 0, mono=bool(self.mono.value),
                                                budget_bytes=int(self.budget.value))

    def show_picture(self, rgb: np.ndarray) -> None:
        self.picture.image = rgb

    def _refresh_image(self) -> None:
        s = self.operator.image_state()
        if s["img"] is None:
            return
        total = s["total_bytes"]
        self.progress.value = 100.0 * s["received_bytes"] / total if total else 0.0
        settings = s["settings"] or {}
        roi = settings.get("roi")
        roi_text = f", ROI {tuple(roi)} shift {settings.get('shift')}" if roi else ""
        self.image_md.content = (
            f"image {s['img']}: {s['received_bytes']}/{total or '?'} bytes, shown {s['decoded_bytes']}"
            f"{' · complete' if s['complete'] else ''}  \n"
            f"{'mono' if settings.get('mono') else 'colour'}, budget {settings.get('budget_bytes')} B{roi_text}")

    # ------------------------------------------------------------------
    # Link health
    # ------------------------------------------------------------------

    def _build_link(self) -> None:
        with self.gui.add_folder("Link"):
            self.link_md = self.gui.add_markdown("*link starting*")

    def _refresh_link(self) -> None:
        s = self.operator.link_state()

        def fmt(v, spec, unit=""):
            return "–" if v is None else f"{v:{spec}}{unit}"

        flags = []
        if s["failsafe"]:
            flags.append("**FAILSAFE**")
        flags.append("AUTOPILOT ok" if s["autopilot"] else "**AUTOPILOT LOST**")
        if not s["link_up"]:
            flags.append("**LINK DOWN**")
        self.link_md.content = (
            "| | |\n|---|---|\n"
            f"| poll rate | {fmt(s['poll_rate_hz'], '.1f', ' Hz')} |\n"
            f"| round trip | {fmt(s['round_trip_s'] and s['round_trip_s'] * 1000, '.0f', ' ms')} |\n"
            f"| replies lost | {s['replies_lost']} of {s['polls_sent']} |\n"
            f"| CRC errors | {s['crc_errors']} |\n"
            f"| traffic | {fmt(s['bytes_per_s'], '.0f', ' B/s')} |\n"
            f"| odometry age | {fmt(s['odometry_age_s'], '.2f', ' s')} |\n"
            f"| images | {s['images_completed']} done, {s['images_abandoned']} abandoned |\n\n"
            + " · ".join(flags))

    # ------------------------------------------------------------------
    # Plots
    # ------------------------------------------------------------------

    def _build_plots(self) -> None:
        empty = np.zeros(2)
        # A fixed window of the last PLOT_SPAN_S seconds: viser's client keeps
        # auto x-scales "relative" across updates, which can lose the data when
        # the chart is laid out late; a static range takes another path.
        x_scale = uplot.Scale(time=False, range=(-PLOT_SPAN_S, 0.0))
        with self.gui.add_folder("Plots"):
            self.plot_axis = self.gui.add_dropdown("Velocity axis", AXES, initial_value="vx")
            self.velocity_plot = self.gui.add_uplot(
                (np.array([-PLOT_SPAN_S, 0.0]), empty, empty),
                (uplot.Series(label="t (s)"),
                 uplot.Series(label="commanded", stroke="#f08c28", width=3.5),
                 uplot.Series(label="received", stroke="#3cb4ff", width=1.5)),
                title="Velocity wish: commanded vs received by the ROV",
                scales={"x": x_scale, "y": uplot.Scale(range=(-1.05, 1.05))},
                aspect=1.6)
            self.link_plot = self.gui.add_uplot(
                (np.array([-PLOT_SPAN_S, 0.0]), empty, empty, empty),
                (uplot.Series(label="t (s)"),
                 uplot.Series(label="sent B/s", stroke="#f08c28", width=1.5),
                 uplot.Series(label="received B/s", stroke="#3cb4ff", width=1.5),
                 uplot.Series(label="replies lost", stroke="#ff4040", width=1.5, scale="n")),
                title="Link time-lapse",
                scales={"x": x_scale, "y": uplot.Scale(auto=True),
                        "n": uplot.Scale(auto=True)},
                axes=(uplot.Axis(), uplot.Axis(scale="y"), uplot.Axis(scale="n", side=1)),
                aspect=1.6)

    def velocity_series(self, now: float, axis: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        column = 1 + AXES.index(axis)
        grid = np.arange(now - PLOT_SPAN_S, now + 1e-9, VELOCITY_STEP_S)
        h = self.operator.history
        return (grid - now, step_values(list(h.commanded), grid, column),
                step_values(list(h.received), grid, column))

    def _refresh_plots(self) -> None:
        now = self.operator.now()
        self.velocity_plot.data = self.velocity_series(now, self.plot_axis.value)
        t, bins = link_bins(list(self.operator.history.link_events), now)
        self.link_plot.data = (t, bins["tx"], bins["rx"], bins["lost"])

    # ------------------------------------------------------------------

    def refresh(self) -> None:
        """Readouts and plots, in place (the scene's thread, 2 Hz)."""
        self._refresh_vehicle()
        self._refresh_image()
        self._refresh_link()
        self._refresh_plots()

