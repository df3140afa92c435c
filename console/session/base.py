"""The ground both sessions stand on (console/session/radio.py `Operator`, the radio
link's, and console/session/acoustic.py `AcousticSession`): what is the same
on every link, written once.

Goal: one session clock, one way to tell subscribers, one log with its alerts
cleared where their condition ends, one switch between a live link and a
replay, and the read side that only reads the parts (console/session/), so
that the two sessions differ only in what their links do.

Plan: `SessionBase` is a base class; a session calls `_start_session` first in
its constructor (clock, lock, subscribers, decode thread, DEBT's warm-up), then
makes its parts (`history`, `health`, `odometry`, `images`, `orders`, `goto`,
`recorder`) and provides the rest of console/session/contract.py's
VehicleSession: `pose_state`, `image_state`, `link_state`, `wish_state`,
`_start_over` (its parts made anew, for `reset`), `_queue_position` (a
POSITION order in its link's encoding, queued) and its other commands.  Like every
part here it never imports the Operator.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from typing import Any, Callable, Iterator

import numpy as np

from rovlink import debt
from rovlink.link.process import LinkProcess
from rovlink.link.report import VehicleReport
from rovlink.link.transports.transport import port_change
from rovlink.link.units import wrap_deg
from rovlink.link.vocabulary import Mode

from .goto import resolve_target
from .images import DaemonWorker, ImageView
from .odometry import LOG_KEPT, LogLine, Pose
from .orders import MODE_NAMES, REPORTED_MODE_NAMES
from .predictor import preview_path
from .world import SAME_POSE_DEG, SAME_POSE_M

MAX_SPEED_MPS = 1.0       # how fast the prediction's uncertainty grows when nothing is heard


class OrderError(ValueError):
    """An order the operator cannot send as given; the message says why."""


class NotNow(OrderError):
    """A well-formed order the link cannot carry, or not now (HTTP 409): sticks on
    the acoustic link, an order before the ROV's first status, during a STOP."""


def mode_of(mode: str | int) -> Mode:
    """The mode a pilot names (a name of MODE_NAMES or its number)."""
    if isinstance(mode, str):
        if mode.upper() not in MODE_NAMES:
            raise OrderError(f"unknown mode {mode!r}; one of {', '.join(MODE_NAMES)}")
        return MODE_NAMES[mode.upper()]
    if mode not in MODE_NAMES.values():
        raise OrderError(f"mode must be 1..6, got {mode!r}")
    return Mode(mode)


class SessionBase:
    """The clock, the subscribers, the log, the replay switch and the shared read
    side of a vehicle session (see the module's docstring for what a session adds)."""

    _logger: logging.Logger  # each session's own: a subscriber's failure is said in its name

    def _start_session(self, clock: Callable[[], float], *, decoder: str, warm_up: str) -> None:
        """What a session is from its start to its end, whatever a replay resets:
        its clock (session time 0 now), lock, subscribers and threads."""
        self._clock = clock
        self._t0 = clock()
        # Clock time of session time 0, for the pilot's clock times (a replay sets the recording's).
        self.wall0 = time.time()
        self._lock = threading.RLock()
        self._subscribers: list[Callable[[str, Any], None]] = []
        self._quiet = False
        self._decoder = DaemonWorker(decoder)
        # DEBT compiles on first use: ahead, in a daemon thread (never holding the exit).
        self._warm_up = debt.warm_up_in_background(warm_up)
        self._port_up: bool | None = None  # the endpoint's port as last seen (`_watch_port`)
        self._link_starts = 0

    def reset(self) -> None:
        """Start the session's state over (a replay seeking back), keeping who the
        session is: its lock, subscribers, decode thread, clock and settings."""
        # Let a decode of the old state finish first: it would land on the new one.
        try:
            self._decoder.submit(lambda: None).result(timeout=10)
        except Exception:  # shut down, or slow: nothing more to wait for
            pass
        with self._lock:
            self._start_over()

    # ------------------------------------------------------------------
    # Time, subscribers, the log
    # ------------------------------------------------------------------

    def now(self) -> float:
        """Session time in seconds (monotonic, 0 at start; simulated in benchmarks)."""
        return self._clock() - self._t0

    def use_clock(self, clock: Callable[[], float], *, wall0: float | None = None) -> None:
        """Session time from `clock` from now on, itself (a replay's timeline)."""
        self._clock, self._t0 = clock, 0.0
        if wall0 is not None:
            self.wall0 = wall0

    def wall(self, t: float) -> float:
        """Clock time (Unix seconds) of session time `t`."""
        return self.wall0 + t

    def subscribe(self, callback: Callable[[str, Any], None]) -> Callable[[], None]:
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def publish(self, topic: str, payload: Any) -> None:
        """Tell every subscriber (the command layer publishes its own events here too)."""
        self._publish(topic, payload)

    def _publish(self, topic: str, payload: Any) -> None:
        if self._quiet:
            return
        for callback in list(self._subscribers):
            try:
                callback(topic, payload)
            except Exception:  # a subscriber's bug never stops the link
                self._logger.exception("subscriber failed on %s", topic)

    @contextlib.contextmanager
    def quiet(self) -> Iterator[None]:
        """Publish nothing inside (a replay's seek), then the resulting state once."""
        self._quiet = True
        try:
            yield
        finally:
            self._quiet = False
        self._publish_settled()

    def _publish_settled(self) -> None:
        """The state a `quiet` spell leaves, told once."""
        self._publish("pose", self.pose_state())
        self._publish("image", self.image_state())

    def note(self, text: str, level: str = "info", *, cause: str | None = None) -> None:
        """A log line. `level`: "alert" (the pilot must see it: link lost, failsafe,
        forged frames, an order refused), "warn", or "info" (routine: an image complete).
        `cause`: the condition an alert is about ("link", "failsafe", "port", "process": the link process), so that
        `clear_alerts` can mark it cleared when the condition ends."""
        line = LogLine(self.now(), text, level, cause)
        self.history.log.append(line)
        self._noted(line)
        self._publish("log", self._log_entry(line))

    def _noted(self, line: LogLine) -> None:
        """A session that keeps its log lines elsewhere too (a recording) does it here."""

    def clear_alerts(self, cause: str) -> None:
        """The condition `cause` has ended: its alerts still standing are marked
        cleared (and published again, so that every page greys them)."""
        t = self.now()
        with self._lock:
            cleared = [line for line in list(self.history.log) if line.cause == cause and line.cleared is None]
            for line in cleared:
                line.cleared = t
        for line in cleared:
            self._publish("log", self._log_entry(line))

    def _log_entry(self, line: LogLine) -> dict:
        return {"t": line.t, "wall": round(self.wall(line.t), 3), "text": line.text, "level": line.level,
                "cause": line.cause, "cleared_wall": None if line.cleared is None else round(self.wall(line.cleared), 3)}

    def log_entries(self, last: int = LOG_KEPT) -> list[dict]:
        return [self._log_entry(line) for line in list(self.history.log)[-last:]]

    # ------------------------------------------------------------------
    # The go-to: the same on every link but for its encoding
    # ------------------------------------------------------------------

    def send_position(self, x_m: float, y_m: float, z_m: float, yaw_deg: float = 0.0, *, relative: bool = False,
                      body: bool = False) -> int:
        """A POSITION order (a go-to), followed from the reports until it arrives or is given up."""
        for name, v in (("x_m", x_m), ("y_m", y_m), ("z_m", z_m), ("yaw_deg", yaw_deg)):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise OrderError(f"{name} must be a finite number, got {v!r}")
        yaw = wrap_deg(yaw_deg)
        # The ROV flies a position order in GUIDED: the pilot is told before it goes.
        order_id = self._queue_position(x_m, y_m, z_m, yaw, relative=relative, body=body,
                                        detail={"x_m": x_m, "y_m": y_m, "z_m": z_m, "yaw_deg": yaw,
                                                "relative": relative, "body": body, "mode": "GUIDED"})
        with self._lock:
            target = resolve_target(x_m, y_m, z_m, yaw, relative=relative, body=body, fix=self.odometry.fix)
            self.goto.started(order_id, target, self.now())
        return order_id

    # ------------------------------------------------------------------
    # The link's surroundings
    # ------------------------------------------------------------------

    # -- why there is no picture yet -------------------------------------------

    _first_report = "report"  # what the ROV's first word is called on this link
    # Why the ROV rejected a FOLLOW that "Frame it" sent (it has no tracker): later ones frame
    # with the ROI alone, until the ROV restarts (it may come back with one).
    follow_refused: str | None = None

    def picture_wait(self) -> str | None:
        """Why there is no picture yet, in the pilot's words; None once there is one."""
        view = self.images.view
        if view.picture is not None or view.images_completed:
            return None
        off = self._pictures_off()
        if off is not None:
            return off
        word = "thumbnail" if self.capabilities.picture == "thumbnail" else "picture"
        state, _ = self.link_condition()
        if state == "replay":
            return f"no {word} in the recording yet"
        if state == "starting":
            return f"waiting for the ROV's first {self._first_report}"
        if state == "lost":
            return f"no {word}: the link is lost"
        return self._picture_wait_on_link()

    def _pictures_off(self) -> str | None:
        """Why no picture is coming at all (the pilot turned them off), or None."""
        return None

    def _picture_wait_on_link(self) -> str:
        """Why there is none yet, the link being up: the driver's words."""
        raise NotImplementedError

    def _machine_lock(self, machine) -> contextlib.AbstractContextManager:
        """What a call into the link's machine is made under: the session's lock where
        the machine runs in this process (the link's loop takes it too); none where it
        runs in a link process.  Its calls may wait `CALL_TIMEOUT_S` there, and the
        session's lock held that long would stall the link's events meanwhile (the
        process's own lock keeps its calls one at a time)."""
        return contextlib.nullcontext() if isinstance(machine, LinkProcess) else self._lock

    def _watch_port(self) -> None:
        """This console's own modem port going down (unplugged, its adapter gone) is
        said at once, loudly, with the transport's reason, beside the lost link it
        causes (not 20 s later on the acoustic link); its coming back clears it."""
        self._port_up, news = port_change(self.endpoint, self._port_up)
        if news is None:
            return
        if not self._port_up:
            self.note(news, "alert", cause="port")
        else:
            self.note(news)
            self.clear_alerts("port")

    def _link_counts(self) -> dict:
        """The driver's own counters, in the neutral words (sent, reports, reports_lost,
        bad_frames, protocol_errors, bytes, images_completed, port_error, the link process)
        and, under its profile's name, what only its link has."""
        raise NotImplementedError

    def link_state(self) -> dict:
        """The link as the pilot is told it (console/session/state.py's LinkState): the
        health's judgement, the neutral counters, each profile's own apart."""
        t = self.now()
        r = self.vehicle()
        return {
            **self.health.state(t, self.rov_failsafe_s),
            **self._link_counts(),
            "odometry_age_s": self.odometry_age_s(),
            "failsafe": bool(r and r.failsafe),
            "autopilot": bool(r and r.autopilot),
            "version": self.link_version,  # "2": every frame authenticated; "1.1": INSECURE; "acoustic"
            "transport_up": self.endpoint.is_up if self.endpoint is not None else False,
            "profile": self.capabilities.profile,
        }

    @staticmethod
    def _link_process_state(link: Any) -> dict:
        """The link state's `link_process` fields: None for a link in this process (or none)."""
        if isinstance(link, LinkProcess):
            return link.link_process_state
        return {"link_process": None, "link_process_reason": None, "link_process_pid": None}

    def close(self) -> None:
        """Close the recording (the link itself belongs to whoever opened it)."""
        self.recorder.close()
        self._decoder.shutdown()

    def wait_debt_idle(self, timeout: float = 300.0) -> bool:
        """Wait until nothing of DEBT runs in this session's threads: its
        warm-up done and every decode handed over so far finished (True), or
        `timeout` seconds (False).  For a caller that needs a quiet moment,
        such as the memory benchmark around tracemalloc's start and stop."""
        deadline = time.monotonic() + timeout
        self._warm_up.join(timeout)
        return not self._warm_up.is_alive() and self._decoder.wait_idle(max(deadline - time.monotonic(), 0.0))

    # ------------------------------------------------------------------
    # A replay shows what was, and sends nothing
    # ------------------------------------------------------------------

    @property
    def replaying(self) -> bool:
        return self.health.replaying

    @replaying.setter
    def replaying(self, value: bool) -> None:
        self.health.replaying = bool(value)

    def replayed_order(self, record: dict) -> None:
        """A recorded order or change of its state, listed as it was."""
        self.orders.replayed(record, self.now())

    # ------------------------------------------------------------------
    # The read side (any thread; no side effects)
    # ------------------------------------------------------------------

    @property
    def lost_after_s(self) -> float:
        return self.health.lost_after_s

    @property
    def image(self) -> ImageView:
        return self.images.view

    def vehicle(self) -> VehicleReport | None:
        """What the ROV last said of itself, in SI, with when it was sampled."""
        fix = self.odometry.fix
        return None if fix is None else fix.report

    def odometry_age_s(self) -> float | None:
        return self.odometry.age_s(self.now())

    def ned_velocity(self) -> tuple[float, float, float, float] | None:
        """Measured north, east, down m/s and yaw deg/s (None before two reports)."""
        with self._lock:
            fix = self.odometry.fix
            return None if fix is None or self.odometry.fixes < 2 else fix.velocity

    def measured_velocity(self) -> dict | None:
        """Speeds from successive received poses (finite differences, smoothed): body
        forward and right, down, and yaw rate; None before two reports."""
        with self._lock:
            return self.odometry.measured_velocity()

    def world_state(self) -> dict:
        """The world as the ROV measured it: the seabed's depth (None: no altitude
        reported, no floor) and the objects it recognised (console/session/world.py)."""
        return self.world.state(self.now())

    def object_approach(self, object_id: int) -> dict | None:
        """A go-to's target that stops short of object `object_id`, facing it (previewed, then
        sent as any go-to); None for an object the ROV does not hold, or before any pose."""
        fix = self.odometry.fix
        if fix is None:
            return None
        return self.world.approach(object_id, fix.pose.x_m, fix.pose.y_m, fix.pose.z_m)

    def when_settled(self, order_id: int, then) -> None:
        """`then(fate, reason)` once order `order_id` is no longer pending (OrderBook.when_settled)."""
        self.orders.when_settled(order_id, then)

    def follow_rejected(self, reason: str) -> None:
        """The ROV rejected a FOLLOW "Frame it" sent: it does not follow (§10). Said once;
        later Frame its send the ROI alone until the ROV restarts."""
        if not self.follow_refused:
            self.note(f"the ROV does not follow (FOLLOW rejected: {reason}): Frame it sends the ROI alone", "warn")
        self.follow_refused = reason or "rejected"

    def order_followed_by(self, order_id: int, then_id: int) -> None:
        """Order `order_id` was followed by order `then_id` that carries on its purpose (a
        rejected FOLLOW's ROI, sent alone): the page shows the second's fate beside the first."""
        self.orders.update(order_id, then=then_id)

    def object_frame(self, object_id: int) -> dict:
        """How "Frame it" frames object `object_id` in the next picture (console/control.py
        FrameObject): the ROI where it lies in the picture taken from where the ROV is now,
        and whether FOLLOW goes with it, drawn on which picture: the one shown when it was
        taken from here (within SAME_POSE_M and SAME_POSE_DEG), else the ROV's newest frame
        where the link can name it; else the ROI alone.  NotNow, in one line, when the
        object is not in view from here (never a wrong ROI); OrderError for no such object."""
        with self._lock:
            fix = self.odometry.fix
        if fix is None:
            raise NotNow("no pose from the ROV yet: nothing can be framed before its first report")
        picture = self.picture()
        caps = self.capabilities
        size = caps.picture_px if picture is None else (int(picture.shape[1]), int(picture.shape[0]))
        if int(object_id) not in self.world.objects:
            raise OrderError(f"no object #{object_id}: the ROV does not hold it")
        roi, words = self.world.frame(object_id, fix.pose, size)
        if roi is None:
            raise NotNow(words)
        plan = {"object_id": int(object_id), "roi": list(roi), "follow": False, "drawn_on": None, "size_px": list(size),
                "text": words}
        if not caps.follow:
            plan["text"] += ": the ROI on the next picture (this link carries no FOLLOW)"
            return plan
        if self.follow_refused:
            plan["text"] += f": the ROI on the next picture (the ROV rejected FOLLOW: {self.follow_refused})"
            return plan
        shown = self.image_state()
        capture = (shown.get("capture") or {}).get("pose")
        if shown.get("img") is not None and capture and _same_place(capture, fix.pose):
            plan.update(follow=True, drawn_on=int(shown["img"]))
            plan["text"] += f": the ROI follows it, drawn on picture {shown['img']} (taken from here)"
        elif caps.follow_newest_frame is not None:
            plan.update(follow=True, drawn_on=caps.follow_newest_frame)
            plan["text"] += ": the ROI follows it from the ROV's newest camera frame"
        else:
            plan["text"] += (": the ROI on the next picture; FOLLOW once a picture taken from here has come "
                             "(Frame it again then)")
        return plan

    def _may_move(self, report: VehicleReport) -> bool:
        """Whether the vehicle may be moving on its own accord at full speed (each
        driver says it for its link: armed on the radio's sticks; armed and not
        holding on the acoustic link's go-tos)."""
        return report.armed

    def uncertainty_m(self) -> float | None:
        """How far the vehicle may be from where it is shown: the odometry's age at
        the most it can move while it may move (or while the link is lost: anything
        may have happened), else only the drift its reports show (a parked vehicle
        wears no ring)."""
        age, fix = self.odometry_age_s(), self.odometry.fix
        if age is None or fix is None:
            return None
        may_move = self._may_move(fix.report) or self.link_condition()[0] == "lost"
        speed = MAX_SPEED_MPS if may_move else math.hypot(*fix.velocity[:3])
        return round(speed * max(0.0, age), 3)

    def _pose_extra(self, report: VehicleReport) -> dict:
        """What a driver's link says of the vehicle beyond the common pose state."""
        return {}

    def pose_state(self) -> dict:
        """The received pose with what the report says, its age and uncertainty, and the
        predicted pose (console/session/state.py's PoseState)."""
        fix = self.odometry.fix
        out: dict[str, Any] = {"t": self.now(), "received": None, "predicted": None}
        if fix is not None:
            r = fix.report
            out["received"] = fix.pose.as_dict()
            out.update(armed=r.armed, mode=REPORTED_MODE_NAMES.get(r.mode, "OTHER"), failsafe=r.failsafe,
                       autopilot=r.autopilot, position_valid=r.position_valid, hold=r.hold,
                       attitude_valid=r.attitude_valid, stopping=self.stopping(),
                       odometry_age_s=self.odometry_age_s(), stale=self.link_condition()[0] == "lost",
                       uncertainty_m=self.uncertainty_m(), **self._pose_extra(r))
            predicted = self.predicted_pose()
            out["predicted"] = predicted.as_dict() if predicted else None
            out["velocity"] = self.measured_velocity()
        return out

    def link_condition(self, t: float | None = None) -> tuple[str, float | None]:
        """("up" | "degraded" | "lost" | "replay" | "starting", seconds since the last report):
        the one definition of a lost link (console.session.health)."""
        return self.health.condition(self.now() if t is None else t)

    def preview_path(self, x_m: float, y_m: float, z_m: float, yaw_deg: float = 0.0, *, seconds: float = 30.0,
                     step_s: float = 0.5) -> list[tuple[float, float, float]]:
        """Where a POSITION order would take the vehicle (GUIDED, from the predicted pose)."""
        start = self.predicted_pose() or Pose(0, 0, 0, 0, 0, 0)
        return preview_path(start, x_m, y_m, z_m, yaw_deg, seconds=seconds, step_s=step_s)

    def image_history(self) -> list[dict]:
        return self.images.history()

    def picture(self) -> np.ndarray | None:
        return self.images.view.picture

    def orders_state(self) -> list[dict]:
        return self.orders.state()

    def state(self) -> dict:
        return {
            "pose": self.pose_state(),
            "image": self.image_state(),
            "link": self.link_state(),
            "velocity_wish": self.wish_state(),
            "orders": self.orders_state(),
            "world": self.world_state(),
            "log": self.log_entries(20),
            "replaying": self.replaying,
            # The session's clock time now: a replay's own (it stands still while paused).
            "wall": round(self.wall(self.now()), 3),
        }


def _same_place(capture: dict, pose: Pose) -> bool:
    """A picture captured at `capture` (a pose's dict) was taken from where `pose` is."""
    try:
        moved = math.dist((capture["x_m"], capture["y_m"], capture["z_m"]), (pose.x_m, pose.y_m, pose.z_m))
        turned = abs(wrap_deg(capture["yaw_deg"] - pose.yaw_deg))
    except (KeyError, TypeError):
        return False
    return moved <= SAME_POSE_M and turned <= SAME_POSE_DEG
