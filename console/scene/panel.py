"""The viser control panel, one per viewer: buttons, sliders, readouts and plots.

Goals
- Everything the pilot does without the mouse in the scene: arm/disarm, mode,
  velocity by sliders and by keys, the supervised Send/Stop, the image settings;
  and everything he must watch: the vehicle's state, the picture and its
  reception progress, the link's health, and two live plots after the paper's
  figures (commanded against received velocity, Fig. 5; a time-lapse of the link's
  traffic and losses, Fig. 4).
- A thin adapter over the command layer (`rovlink.console.control`), as
  nerfstudio's control panel is over its viewer: it is handed its callbacks
  (`PanelCallbacks`) and never imports the scene.  Every control builds one
  typed order and hands it to `submit` (the scene's desk, with this viewer's
  caller); it holds no order of its own.  What a control shows comes from the operator's
  events (`render_*`), never from an earlier touch, so that no widget can resend
  an old value.
- Built per viewer on its own `client.gui` (viser's camera-poses example): a
  viewer that may not order sees its order controls disabled (`set_permitted`),
  STOP excepted.
- The view (follow, top, free; centre on the vehicle) is the viewer's own, not
  an order: open to watchers too.  A legend says what each colour in the scene is.
  Both sit in a small window of their own in the 3-D view's lower left corner
  (viser's `add_panel`), so that they stay at hand when the main panel is
  minimized, as it is in the operator page.

Keys follow the page's model: a held key drives (a press streams the key's
velocity, which goes neutral after the dead man's time unless the press repeats),
Space is STOP.  viser reports key presses, not releases: nothing latches.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from viser import uplot

from rovlink.console import control
from rovlink.console.control import AXES, KEY_GAIN, KEYS, LIMITS, MODES, NotHolder
from rovlink.console.scene import chase
from rovlink.console.scene.colours import (
    CAPTURE_RGB,
    FOLLOW_RGB,
    FRUSTUM_RGB,
    GHOST_RGB,
    ROV_RGB,
    TARGET_RGB,
    UNCERTAINTY_RGB,
)
from rovlink.console.session.base import OrderError

log = logging.getLogger("rovlink.console.scene.panel")

AXIS_LABELS = {"vx": "Surge (forward +)", "vy": "Sway (right +)", "vz": "Heave (down +)", "vyaw": "Yaw (clockwise +)"}
PLOT_SPAN_S = 30.0
VELOCITY_STEP_S = 0.1
LINK_BIN_S = 0.5
REFUSAL_NOTICE_S = 3.0  # at most one "not sent" notification per viewer this often
VIEW_PANEL_WIDTH_PX = 230


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


def link_summary(s: dict) -> str:
    """The link's state in one line, as the page says it."""
    state = s.get("state")
    if state == "replay":
        return "**REPLAY** (a recording, no ROV)"
    if state == "lost":
        since = s.get("since_reply_s")
        text = f"**LINK LOST**: no reply for {since:.1f} s" if since is not None else "**LINK LOST**"
        if s.get("failsafe_inferred"):
            text += f" · **ROV in FAILSAFE (inferred) since {s['failsafe_inferred_since']}**"
        return text
    if state == "degraded":
        return f"link degraded: {s['degraded_reason']}" if s.get("degraded_reason") else "link degraded"
    return "link up" if state == "up" else "link starting"


def legend_html() -> str:
    """What each thing drawn in the scene is, in its colour."""

    def swatch(rgb, text: str, opacity: float = 1.0) -> str:
        r, g, b = rgb
        return (f'<div style="display:flex;align-items:center;gap:0.5em;margin:0.1em 0;white-space:nowrap">'
                f'<span style="display:inline-block;width:1.6em;height:0.8em;border-radius:2px;'
                f'background:rgba({r},{g},{b},{opacity})"></span><span>{text}</span></div>')

    return ('<div style="font-size:0.75em;line-height:1.25">'
            + swatch(ROV_RGB, "vehicle: last pose received")
            + swatch(GHOST_RGB, "ghost: pose predicted now", 0.8)
            + swatch(UNCERTAINTY_RGB, "ring: how far off it may be")
            + swatch(TARGET_RGB, "target and path (sent on Send)", 0.6)
            + swatch(ROV_RGB, "line: trail of poses received")
            + swatch(FRUSTUM_RGB, "camera now, its seabed footprint")
            + swatch(CAPTURE_RGB, "camera at the picture's capture")
            + swatch(FOLLOW_RGB, "ray to the followed object (Follow)")
            + "</div>")


@dataclass(frozen=True)
class PanelCallbacks:
    """What a panel may do beyond showing the session: handed in by whoever
    builds it (the scene, per viewer), as nerfstudio's control panel is."""

    submit: Callable[[object], object]  # carry an order out for this viewer (raises NotHolder or OrderError)
    notify: Callable[[str, str], None] | None = None  # tell the viewer why not (title, text)
    refused: Callable[[], None] | None = None  # an order was refused (the scene counts them)
    set_view: Callable[[str], None] | None = None  # this viewer's camera: follow, top or free
    centre_view: Callable[[], None] | None = None  # this viewer's camera onto the vehicle
    # The simulator's own seabed shown or hidden (its truth, not measured): `rovlink demo` only.
    sim_seabed: Callable[[bool], None] | None = None


class ControlPanel:
    """One viewer's panel over `session` (the Operator: read, never ordered
    directly).  Orders leave through `callbacks.submit` only."""

    def __init__(self, gui, session, callbacks: PanelCallbacks, *, image_px: tuple[int, int],
                 target: dict | None = None) -> None:
        self.gui = gui
        self.operator = session
        self.callbacks = callbacks
        self.image_px = image_px
        self._refused_at = -1e9
        # Renders assign values, and viser calls our callbacks for them (client
        # None, this thread): `_rendering` tells them not to order.
        self._rendering = threading.local()
        self.order_widgets: list = []
        self.permitted: bool | None = None
        self._build_view()
        self._build_vehicle()
        # What the link cannot carry is left out (the acoustic link has no sticks), never shown to fail.
        self.sticks = session.capabilities.velocity
        self.sliders: dict = {}
        if self.sticks:
            self._build_velocity()
        self._build_keys()
        self._build_target()
        self._build_image()
        self._build_world()
        self._build_link()
        self._build_plots()
        self.render_wish(self.operator.wish_state())
        self.render_target(target)
        self.render_image_settings()

    # ------------------------------------------------------------------
    # The one way out
    # ------------------------------------------------------------------

    def submit(self, order):
        """Hand `order` to the command layer; a refusal is shown, not raised."""
        callbacks = self.callbacks
        try:
            return callbacks.submit(order)
        except (NotHolder, OrderError) as exc:
            now = time.monotonic()
            if callbacks.notify is not None and now - self._refused_at >= REFUSAL_NOTICE_S:
                self._refused_at = now
                callbacks.notify("Not sent", str(exc))
            if callbacks.refused is not None:
                callbacks.refused()
            return None

    def _on(self, handle, make_order: Callable) -> None:
        """A control whose change (by the viewer, not a render) submits make_order()."""
        def on_update(_event) -> None:
            if getattr(self._rendering, "on", False):
                return
            order = make_order()
            if order is not None:
                self.submit(order)

        handle.on_update(on_update)

    def _render(self, fn: Callable) -> None:
        self._rendering.on = True
        try:
            fn()
        finally:
            self._rendering.on = False

    def set_permitted(self, permitted: bool) -> None:
        """Order controls enabled only for a viewer who may order (STOP always)."""
        if permitted == self.permitted:
            return
        self.permitted = permitted
        for handle in self.order_widgets:
            handle.disabled = not permitted
        self.control_md.content = ("You may order from this view." if permitted else
                                   "**Watching**: take control on the operator page to order from this view. "
                                   "STOP (Space) works for everyone.")

    # ------------------------------------------------------------------
    # View: this viewer's camera, and the legend
    # ------------------------------------------------------------------

    def _build_view(self) -> None:
        add_panel = getattr(self.gui, "add_panel", None)  # viser >= 1.1
        self.view_panel = None
        if self.callbacks.set_view is not None and add_panel is not None:
            self.view_panel = add_panel()
            container = self.view_panel.add_tab("View")
        else:  # an older viser, or a panel for the whole server: a folder in the main panel
            container = self.gui.add_folder("View")
        with container:
            self.view = self.gui.add_dropdown("View", chase.VIEWS, initial_value=chase.FOLLOW,
                                              hint="; ".join(chase.VIEW_LABELS[v] for v in chase.VIEWS))
            self.centre_button = self.gui.add_button("Centre on vehicle")
            self.legend = self.gui.add_html(legend_html())
            self.sim_seabed = None
            if self.callbacks.sim_seabed is not None:
                self.sim_seabed = self.gui.add_checkbox(
                    "Simulator's seabed (truth)", initial_value=False,
                    hint="the simulator's own seabed, not measured: the floor drawn is the one the ROV measured")
        if self.view_panel is not None:
            self.view_panel.float(x=10, y=-10, width=VIEW_PANEL_WIDTH_PX)  # the lower left corner
        set_view, centre_view = self.callbacks.set_view, self.callbacks.centre_view
        if set_view is not None:
            self.view.on_update(lambda _event: set_view(self.view.value))
        if centre_view is not None:
            self.centre_button.on_click(lambda _event: centre_view())
        if self.sim_seabed is not None:
            show = self.callbacks.sim_seabed
            self.sim_seabed.on_update(lambda _event: show(bool(self.sim_seabed.value)))

    # ------------------------------------------------------------------
    # Vehicle: arm, mode, state
    # ------------------------------------------------------------------

    def _build_vehicle(self) -> None:
        with self.gui.add_folder("Vehicle"):
            self.control_md = self.gui.add_markdown("")
            self.vehicle_md = self.gui.add_markdown("*waiting for the first odometry*")
            self.arm_button = self.gui.add_button("Arm", color="orange")
            self.disarm_button = self.gui.add_button("Disarm")
            self.mode = self.gui.add_dropdown("Mode", MODES, initial_value=MODES[0])
            self.set_mode_button = self.gui.add_button("Set mode")
        self.order_widgets += [self.arm_button, self.disarm_button, self.mode, self.set_mode_button]
        self.arm_button.on_click(lambda _event: self.submit(control.Arm(True)))
        self.disarm_button.on_click(lambda _event: self.submit(control.Arm(False)))
        self.set_mode_button.on_click(lambda _event: self.request_mode())

    def request_mode(self):
        return self.submit(control.SetMode(self.mode.value))

    def _refresh_vehicle(self, state: dict, link: dict) -> None:
        pose = state.get("received")
        if pose is None:
            return
        flags = " · ".join(f for f, on in (("**FAILSAFE**", state.get("failsafe")),
                                             ("autopilot lost", not state.get("autopilot")),
                                             ("**STOP in force**", state.get("stopping")),
                                             ("HOLD (centre the sticks)", state.get("hold")),
                                             ("attitude not measured", state.get("attitude_valid") is False)) if on)
        stale = " · *(old: the link is lost)*" if state.get("stale") else ""
        self.vehicle_md.content = (
            f"{'**ARMED**' if state.get('armed') else 'disarmed'} · {state.get('mode')}"
            f"{' · ' + flags if flags else ''}{stale}  \n"
            f"N {pose['x_m']:+.2f} m, E {pose['y_m']:+.2f} m, depth {pose['z_m']:.2f} m, "
            f"heading {pose['yaw_deg'] % 360:.0f}°")

    # ------------------------------------------------------------------
    # Velocity: sliders show the wish; a touch changes one axis of it
    # ------------------------------------------------------------------

    def _build_velocity(self) -> None:
        lo, hi = LIMITS["velocity"]
        with self.gui.add_folder("Velocity"):
            self.sliders = {a: self.gui.add_slider(AXIS_LABELS[a], min=lo, max=hi, step=0.05, initial_value=0.0)
                            for a in AXES}
            self.zero_button = self.gui.add_button("Zero velocity (X)")
            keys = ", ".join(f"{k} {axis}{'+' if sign > 0 else '-'}" for k, (axis, sign) in KEYS.items())
            self.gui.add_markdown(f"Hold a key to drive ({keys}), {KEY_GAIN:g} of the maximum; it stops when "
                                  f"released. Space = STOP. The sliders show the wish, whoever set it.")
        self.order_widgets += [*self.sliders.values(), self.zero_button]
        for axis, slider in self.sliders.items():
            self._on(slider, lambda axis=axis, slider=slider: self.velocity_with(axis, float(slider.value)))
        self.zero_button.on_click(lambda _event: self.submit(control.Drive()))

    def velocity_with(self, axis: str, value: float, streamed: bool = False) -> control.Drive:
        """The wish as it is now, one axis changed: a touch never resends
        what another control showed before."""
        wish = dict(self.operator.wish_state())
        wish[axis] = round(min(1.0, max(-1.0, value)), 3)
        return control.Drive(**wish, streamed=streamed)

    def render_wish(self, wish: dict) -> None:
        def show() -> None:
            for axis, slider in self.sliders.items():
                if abs(slider.value - wish[axis]) > 1e-6:
                    slider.value = wish[axis]
        self._render(show)

    def _build_keys(self) -> None:
        self.key_commands = []
        if self.sticks:
            for key, (axis, sign) in KEYS.items():
                command = self.gui.add_command(f"Drive {axis} {'+' if sign > 0 else '-'}", hotkey=key)
                command.on_trigger(lambda _event, axis=axis, sign=sign: self.key_drive(axis, sign))
                self.key_commands.append(command)
            zero = self.gui.add_command("Zero velocity", hotkey="X")
            zero.on_trigger(lambda _event: self.submit(control.Drive()))
            self.order_widgets += [*self.key_commands, zero]
        self.stop_command = self.gui.add_command("STOP", hotkey="space")
        self.stop_command.on_trigger(lambda _event: self.stop())

    def key_drive(self, axis: str, sign: int):
        """A key press: this axis at the key's strength, streamed (the dead man
        brings it back to neutral unless the press repeats)."""
        return self.submit(self.velocity_with(axis, sign * KEY_GAIN, streamed=True))

    def stop(self):
        return self.submit(control.Stop())

    # ------------------------------------------------------------------
    # Supervised control: the shared target
    # ------------------------------------------------------------------

    def _build_target(self) -> None:
        with self.gui.add_folder("Target"):
            self.target_md = self.gui.add_markdown("")
            self.send_button = self.gui.add_button("Send (switches to GUIDED)", color="green", disabled=True)
            self.stop_button = self.gui.add_button("Stop", color="red")
            self.reset_button = self.gui.add_button("Reset target")
        self.order_widgets += [self.reset_button]
        self.send_button.on_click(lambda _event: self.submit(control.SendTarget()))
        self.stop_button.on_click(lambda _event: self.stop())  # anyone may stop
        self.reset_button.on_click(lambda _event: self.submit(control.ClearTarget()))

    def render_target(self, target: dict | None) -> None:
        if target is None:
            self.target_md.content = ("No target. Move the gizmo to set one; the path is previewed, nothing is "
                                      "sent before **Send**, which switches the vehicle to **GUIDED**.")
            self.send_button.disabled = True
            return
        sent = f"sent as order {target['order_id']}" if target["sent"] else "**not sent**"
        self.target_md.content = (f"Target N {target['x_m']:+.2f} E {target['y_m']:+.2f} depth "
                                  f"{target['z_m']:.2f} m, heading {target['yaw_deg'] % 360:.0f}° — {sent}")
        self.send_button.disabled = bool(target["sent"]) or not self.permitted

    # ------------------------------------------------------------------
    # Image: picture, progress, settings
    # ------------------------------------------------------------------

    def _build_image(self) -> None:
        settings = self.operator.requested_settings
        caps = self.operator.capabilities
        with self.gui.add_folder("Image"):
            w, h = self.image_px
            self.picture = self.gui.add_image(np.full((h, w, 3), 30, np.uint8), label="Latest image",
                                              format="jpeg", jpeg_quality=90)
            self.progress = self.gui.add_progress_bar(0.0, color="cyan")
            self.image_md = self.gui.add_markdown("*no image yet*")
            budget_max = caps.image_budget_max  # the link's, not the radio's
            self.budget = self.gui.add_slider("Budget (bytes)", min=200, max=budget_max, step=100,
                                              initial_value=int(min(budget_max, max(200, settings.budget_bytes))))
            self.shift_slider = self.gui.add_slider("ROI shift", min=LIMITS["shift"][0], max=LIMITS["shift"][1],
                                                    step=1, initial_value=settings.shift or 4)
            self.mono = self.gui.add_checkbox("Mono", initial_value=settings.mono)
            self.apply_button = self.gui.add_button("Apply image settings")
            self.clear_roi_button = self.gui.add_button("Clear ROI")
            self.follow_button = self.gui.add_button("Follow ROI", visible=caps.follow)
            self.next_button = self.gui.add_button("Next image", visible=caps.next_image)
            self.gui.add_markdown("Drag a rectangle on the picture in the scene to set the ROI; "
                                  "Follow ROI: the ROV keeps it on what it framed.")
        self.order_widgets += [self.budget, self.shift_slider, self.mono, self.apply_button, self.clear_roi_button,
                               self.follow_button, self.next_button]
        self.follow_button.on_click(lambda _event: self.follow_roi())
        self.apply_button.on_click(lambda _event: self.apply_image_settings())
        self.clear_roi_button.on_click(lambda _event: self.submit(control.ChangeImage(roi=None)))
        self.next_button.on_click(lambda _event: self.submit(control.NextImage()))

    @property
    def shift(self) -> int:
        return int(self.shift_slider.value)

    def apply_image_settings(self):
        roi = self.operator.requested_settings.roi  # keep the ROI the pilot drew
        return self.submit(control.ChangeImage(roi=roi, shift=self.shift if roi else 0, mono=bool(self.mono.value),
                                               budget_bytes=int(self.budget.value)))

    def follow_roi(self):
        """FOLLOW (docs/PROTOCOL.md §10) of the ROI last requested, drawn on the picture shown now."""
        roi = self.operator.requested_settings.roi
        img = self.operator.image_state()["img"]
        if roi is None or img is None:
            if self.callbacks.notify is not None:
                self.callbacks.notify("No ROI to follow", "Drag a rectangle on the picture first.")
            return None
        return self.submit(control.FollowRoi(roi=tuple(roi), keep=True, drawn_on=img))

    def render_image_settings(self) -> None:
        """The settings last requested, whoever requested them."""
        s = self.operator.requested_settings

        def show() -> None:
            budget = int(min(self.operator.capabilities.image_budget_max, max(200, s.budget_bytes)))
            if self.budget.value != budget:
                self.budget.value = budget
            if s.shift and self.shift_slider.value != s.shift:
                self.shift_slider.value = s.shift
            if self.mono.value != s.mono:
                self.mono.value = s.mono
        self._render(show)

    def show_picture(self, rgb: np.ndarray) -> None:
        self.picture.image = rgb

    def _refresh_image(self, s: dict) -> None:
        if s["img"] is None:
            return
        total = s["total_bytes"]
        self.progress.value = 100.0 * s["received_bytes"] / total if total else 0.0
        settings = s["settings"] or {}
        roi = settings.get("roi")
        roi_text = f", ROI {tuple(roi)} shift {settings.get('shift')}" if roi else ""
        track = s.get("track")
        if track:
            lost = f" for {track['lost_for_s']:.1f} s" if track["state"] != "holds" else ""
            roi_text += f", track {track['state']}{lost}"
        self.image_md.content = (
            f"image {s['img']}: {s['received_bytes']}/{total or '?'} bytes, shown {s['decoded_bytes']}"
            f"{' · complete' if s['complete'] else ''}  \n"
            f"{'mono' if settings.get('mono') else 'colour'}, budget {settings.get('budget_bytes')} B{roi_text}")

    # ------------------------------------------------------------------
    # The world the ROV measured: the seabed, and the object selected in the scene
    # ------------------------------------------------------------------

    def _build_world(self) -> None:
        self.selected_object: int | None = None
        self._frame_order: int | None = None
        self._frame_text = ""
        with self.gui.add_folder("Seabed and objects"):
            self.world_md = self.gui.add_markdown("seabed depth unknown: no report yet")
            self.object_md = self.gui.add_markdown("*Click an object in the scene to select it.*")
            self.object_goto_button = self.gui.add_button(
                "Go to object (preview)", hint="a go-to that stops short of it, facing it: previewed; Send sends it")
            self.object_frame_button = self.gui.add_button(
                "Frame it", hint="the next picture's ROI on it, and FOLLOW where the link carries it")
            self.object_fate_md = self.gui.add_markdown("")
        self.order_widgets += [self.object_goto_button, self.object_frame_button]
        self.object_goto_button.on_click(lambda _event: self.goto_object())
        self.object_frame_button.on_click(lambda _event: self.frame_object())

    def select_object(self, obj: dict) -> None:
        """The object clicked in the scene (a WorldState object) is the one Go to and Frame it act on."""
        self.selected_object = int(obj["id"])
        self._frame_order = None
        self.object_fate_md.content = ""
        self._show_object(obj)

    def _show_object(self, obj: dict | None) -> None:
        if obj is None:
            self.object_md.content = f"Object #{self.selected_object} **removed by the ROV**."
            return
        self.object_md.content = (
            f"**Object #{obj['id']}: {obj['class']}** {obj['length_m']:.1f} x {obj['width_m']:.1f} m at "
            f"N {obj['north_m']:+.1f} E {obj['east_m']:+.1f}, heading {obj['heading_deg']:.0f}°, "
            f"{obj['confidence']:.0%}, seen {obj.get('age_s', 0):.0f} s ago")

    def _why_not(self, exc: Exception) -> None:
        self.object_fate_md.content = f"**Not sent**: {exc}"
        if self.callbacks.refused is not None:
            self.callbacks.refused()

    def goto_object(self):
        """Preview a go-to to the selected object's stand-off, facing it (Send sends it, as any target)."""
        if self.selected_object is None:
            self.object_fate_md.content = "Click an object in the scene first."
            return None
        target = self.operator.object_approach(self.selected_object)
        if target is None:
            self.object_fate_md.content = f"Object #{self.selected_object} is no longer held (or no pose yet)."
            return None
        try:
            points = self.callbacks.submit(control.PreviewTarget(target["x_m"], target["y_m"], target["z_m"],
                                                                 target["yaw_deg"]))
        except (NotHolder, OrderError) as exc:
            return self._why_not(exc)
        self.object_fate_md.content = (f"Go-to previewed: {target['standoff_m']:g} m short of it, facing it; "
                                       "**Send** (Target) sends it, switching to GUIDED.")
        return points

    def frame_object(self):
        """Frame it (console/control.py FrameObject): its fate, or why not, under the buttons."""
        if self.selected_object is None:
            self.object_fate_md.content = "Click an object in the scene first."
            return None
        try:
            result = self.callbacks.submit(control.FrameObject(self.selected_object))
        except (NotHolder, OrderError) as exc:
            return self._why_not(exc)
        self._frame_order = result["id"]
        self._frame_text = f"{result['text']}: ROI {tuple(result['roi'])}"
        self.object_fate_md.content = self._frame_text
        return result

    def _refresh_world(self, w: dict) -> None:
        text = (f"seabed depth unknown: {w['seabed_unknown_why']} (no floor drawn)" if w["seabed_depth_m"] is None
                else f"seabed at {w['seabed_depth_m']:.1f} m (altitude {w['altitude_m']:.1f} m, "
                     f"{w['altitude_age_s']:.0f} s ago{', OLD' if w['altitude_stale'] else ''}); "
                     f"{len(w['objects'])} objects (click one)")
        if self.world_md.content != text:
            self.world_md.content = text
        if self.selected_object is None:
            return
        self._show_object(next((o for o in w["objects"] if o["id"] == self.selected_object), None))
        if self._frame_order is not None:
            orders = {o["id"]: o for o in self.operator.orders_state()}
            order = orders.get(self._frame_order)
            if order is not None:
                text = f"{self._frame_text} · order #{order['id']} {order['text']}"
                if order.get("then"):  # a FOLLOW the ROV rejected: its ROI sent alone
                    then = orders.get(order["then"])
                    text += f"; the ROI alone: order #{order['then']} {then['text'] if then else 'queued'}"
                self.object_fate_md.content = text

    # ------------------------------------------------------------------
    # Link health
    # ------------------------------------------------------------------

    def _build_link(self) -> None:
        with self.gui.add_folder("Link"):
            self.link_md = self.gui.add_markdown("*link starting*")

    def _refresh_link(self, s: dict) -> None:
        def fmt(v, spec, unit=""):
            return "–" if v is None else f"{v:{spec}}{unit}"

        flags = []
        if s["failsafe"]:
            flags.append("**FAILSAFE**")
        flags.append("AUTOPILOT ok" if s["autopilot"] else "**AUTOPILOT LOST**")
        self.link_md.content = (
            f"{link_summary(s)}\n\n"
            "| | |\n|---|---|\n"
            f"| replies | {fmt(s['reply_rate_hz'], '.1f', ' Hz')} (polls {fmt(s['poll_rate_hz'], '.1f', ' Hz')}) |\n"
            f"| since reply | {fmt(s['since_reply_s'], '.1f', ' s')} |\n"
            f"| round trip | {fmt(s['round_trip_s'] and s['round_trip_s'] * 1000, '.0f', ' ms')} |\n"
            f"| reports lost | {'—' if s['reports_lost'] is None else s['reports_lost']} of {s['sent']} sent |\n"
            f"| bad frames | {s['bad_frames']} |\n"
            f"| traffic | {fmt(s['bytes_per_s'], '.0f', ' B/s')} |\n"
            f"| images | {s['images_completed']} done"
            + (f", {s['radio']['images_abandoned']} abandoned" if s.get("radio") else "") + " |\n\n"
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
        with self.gui.add_folder("Plots", expand_by_default=False):
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

    def refresh(self, pose: dict | None = None, link: dict | None = None, image: dict | None = None) -> None:
        """Readouts and plots, in place (the scene's thread, 2 Hz)."""
        pose = self.operator.pose_state() if pose is None else pose
        link = self.operator.link_state() if link is None else link
        image = self.operator.image_state() if image is None else image
        self._refresh_vehicle(pose, link)
        self._refresh_image(image)
        self._refresh_world(self.operator.world_state())
        self._refresh_link(link)
        self._refresh_plots()
