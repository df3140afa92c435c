"""The acoustic profile over the emulated Modem-M64, in simulated time.

Goals: run AcousticOperator (side "a", the modem of role a) and AcousticRov
(side "b") over `link.m64.M64Channel` exactly as the real programs will
drive them over `wlmodem`: a machine is asked for a packet only when its
modem's transmit queue is empty (`queue_length`), and the modem is flushed
first when it `wants_flush` (a STOP, a SYNC).  Around them, the least a test
or the bench needs: a vehicle that flies a go-to at 0.5 m/s and takes the
other orders at once, and a camera that makes thumbnail objects of the size DEBT
makes for the budget asked (or hands a fixed object).

Plan: a loop over simulated time that jumps to the next thing that can
happen (a packet arrives or leaves, a scheduled callback, the ROV's
failsafe), and never further than `step_s` (0.1 s): the vehicle moves and
the machines may want to send.  Events of both machines are kept with their
time (`op_log`, `rov_log`) and handed to optional callbacks.
"""

from __future__ import annotations

import heapq
import math
import os
import random
from typing import Callable

from .. import acoustic as ac
from ..emulators.m64 import M64Channel, M64Loss, M64Params
from ..vocabulary import Mode

GOTO_SPEED = 0.5  # m/s
SURFACE_SPEED = 0.25  # m/s up


def budget_camera(settings: ac.ThumbRequest) -> bytes:
    """A thumbnail object of the size DEBT makes for the settings' budget ([N:2] and
    BUDGET bytes: DEBT fills its budget), its bytes stand-ins.  What a picture shows is
    not the link's business (and `link` knows nothing of the codec); the two-process
    test (tests/console/test_acoustic.py) decodes a real one."""
    stream = random.Random(settings.oid).randbytes(settings.budget)
    return len(stream).to_bytes(2, "big") + stream


def fixed_camera(size: int = 200, seed: int = 7) -> Callable[[ac.ThumbRequest], bytes]:
    stream = random.Random(seed).randbytes(size - 2)
    return lambda settings: len(stream).to_bytes(2, "big") + stream


class SimVehicle:
    """Just enough vehicle: local NED position, heading, armed, mode; orders at once."""

    def __init__(self, *, armed: bool = True, position_valid: bool = True, autopilot: bool = True,
                 arm_delay_s: float = 0.0) -> None:
        self.x = self.y = 0.0
        self.z = 5.0
        self.heading = 0.0
        self.armed = armed
        self.position_valid = position_valid
        self.autopilot = autopilot
        self.mode = Mode.POS_HOLD
        self.target: tuple[float, float, float] | None = None
        self.goto_oid: int | None = None
        self.surfacing_oid: int | None = None
        self.battery = 15.8
        # An ARM taken now and done this long after (a vehicle finishing its checks); 0: at once.
        self.arm_delay_s = arm_delay_s
        self.arming: tuple[int, float] | None = None  # (OID, seconds left)

    def state(self) -> ac.VehicleState:
        return ac.VehicleState(self.x, self.y, self.z, self.heading, self.armed, self.mode, self.position_valid,
                               self.autopilot, self.autopilot, self.target is not None, self.battery)

    def brake(self) -> None:
        self.target = None
        self.goto_oid = self.surfacing_oid = None
        self.mode = Mode.POS_HOLD if self.position_valid else Mode.DEPTH_HOLD

    def step(self, dt: float, rov: ac.AcousticRov) -> None:
        if self.arming is not None:
            oid, left = self.arming
            self.arming = None if left <= dt else (oid, left - dt)
            if self.arming is None:
                self.armed = True
                rov.order_outcome(oid, ac.R_DONE)
        if self.surfacing_oid is not None:
            self.z = max(0.0, self.z - SURFACE_SPEED * dt)
            if self.z == 0.0:
                rov.order_outcome(self.surfacing_oid, ac.R_DONE)
                self.surfacing_oid = None
        if self.target is None:
            return
        tx, ty, tz = self.target
        dx, dy, dz = tx - self.x, ty - self.y, tz - self.z
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        move = GOTO_SPEED * dt
        if dist <= move:
            self.x, self.y, self.z = tx, ty, tz
            self.target = None
            self.mode = Mode.POS_HOLD
            if self.goto_oid is not None:
                rov.order_outcome(self.goto_oid, ac.R_DONE)
            self.goto_oid = None
        else:
            f = move / dist
            self.x += dx * f
            self.y += dy * f
            self.z += dz * f

    def handle(self, event, rov: ac.AcousticRov, failsafe_action: int) -> None:
        if isinstance(event, ac.StopWanted):
            self.brake()
        elif isinstance(event, ac.FailsafeStarted):
            self.brake()
            if event.action == ac.FAILSAFE_SURFACE:
                self.mode = Mode.SURFACE
                self.surfacing_oid = -1
        elif isinstance(event, ac.HoldWanted):
            self.brake()
            rov.order_outcome(event.oid, ac.R_DONE)
        elif isinstance(event, ac.SurfaceWanted):
            self.brake()
            self.mode = Mode.SURFACE
            self.surfacing_oid = event.oid
        elif isinstance(event, ac.ArmWanted):
            if self.arm_delay_s > 0 and not self.armed:
                self.arming = (event.oid, self.arm_delay_s)
                rov.order_outcome(event.oid, ac.R_TAKEN)
            else:
                self.armed = True
                rov.order_outcome(event.oid, ac.R_DONE)
        elif isinstance(event, ac.DisarmWanted):
            self.armed = False
            self.brake()
            rov.order_outcome(event.oid, ac.R_DONE)
        elif isinstance(event, ac.ModeWanted):
            self.target = None
            self.mode = Mode(event.mode)
            rov.order_outcome(event.oid, ac.R_DONE)
        elif isinstance(event, ac.GoToWanted):
            g = event.target
            x, y, z = g.x_dm / 10, g.y_dm / 10, g.z_dm / 10
            if g.relative:
                if g.body_frame:
                    h = math.radians(self.heading)
                    x, y = x * math.cos(h) - y * math.sin(h), x * math.sin(h) + y * math.cos(h)
                x, y, z = self.x + x, self.y + y, self.z + z
            self.surfacing_oid = None
            self.target = (x, y, max(0.0, z))
            self.goto_oid = event.oid
            self.mode = Mode.GUIDED
            if g.yaw_set:
                self.heading = (self.heading + g.yaw_cdeg / 100) % 360 if g.relative else g.yaw_cdeg / 100 % 360


class AcousticSim:
    """Operator (side a) and ROV (side b) over an emulated M64 pair."""

    def __init__(self, key: bytes | None = None, *, loss: float = 0.0, burst: float = 1.0, seed: int = 0,
                 failsafe_s: int = ac.FAILSAFE_S, failsafe_action: int = ac.FAILSAFE_HOLD,
                 camera: Callable[[ac.ThumbRequest], bytes] | None = None, vehicle: SimVehicle | None = None,
                 params: M64Params | None = None, step_s: float = 0.1, start: float = 0.0,
                 on_operator_event: Callable[[object, float], None] | None = None,
                 on_rov_event: Callable[[object, float], None] | None = None) -> None:
        rng = random.Random(seed)
        self.key = key if key is not None else rng.randbytes(32)
        self._rng = rng
        self.channel = M64Channel(params, M64Loss(loss, burst), M64Loss(loss, burst), seed=seed, start=start)
        self.failsafe_s, self.failsafe_action = failsafe_s, failsafe_action
        self.operator = ac.AcousticOperator(self.key, random_bytes=rng.randbytes)
        self.rov = self._new_rov()
        self.vehicle = vehicle or SimVehicle()
        self.camera = camera or budget_camera
        self.step_s = step_s
        self.now = start
        self.op_log: list[tuple[float, object]] = []
        self.rov_log: list[tuple[float, object]] = []
        self.on_operator_event = on_operator_event
        self.on_rov_event = on_rov_event
        self.rov_down = False
        self.handed: dict[str, list[tuple[float, bytes]]] = {"a": [], "b": []}  # every packet handed, with its time
        self.tamper: Callable[[str, bytes, float], bytes | None] | None = None  # (to, packet, now) -> packet or None
        self._timers: list[tuple[float, int, Callable[[float], None]]] = []
        self._seq = 0

    def _new_rov(self) -> ac.AcousticRov:
        return ac.AcousticRov(self.key, failsafe_s=self.failsafe_s, failsafe_action=self.failsafe_action,
                              random_bytes=self._rng.randbytes)

    def restart_rov(self) -> None:
        """The ROV's process starts again (a new BOOT); the vehicle brakes."""
        self.rov = self._new_rov()
        self.vehicle.brake()
        self.channel.flush("b", self.now)

    def at(self, t: float, fn: Callable[[float], None]) -> None:
        self._seq += 1
        heapq.heappush(self._timers, (t, self._seq, fn))

    # -- events ------------------------------------------------------------------

    def _op_events(self, events) -> None:
        for e in events:
            self.op_log.append((self.now, e))
            if self.on_operator_event:
                self.on_operator_event(e, self.now)

    def _rov_events(self, events) -> None:
        for e in events:
            self.rov_log.append((self.now, e))
            if self.on_rov_event:
                self.on_rov_event(e, self.now)
            if isinstance(e, ac.ThumbnailWanted):
                self.rov.thumbnail_ready(e.oid, self.camera(e.settings))
            else:
                self.vehicle.handle(e, self.rov, self.failsafe_action)
        self.rov.update_status(self.vehicle.state())

    # -- the pilot -----------------------------------------------------------------

    def stop(self) -> int:
        return self.operator.stop(self.now)

    def order(self, body) -> int:
        return self.operator.send_order(body, self.now)

    def events(self, kind, side: str = "operator") -> list[tuple[float, object]]:
        log = self.op_log if side == "operator" else self.rov_log
        return [(t, e) for t, e in log if isinstance(e, kind)]

    # -- the loop --------------------------------------------------------------------

    def _feed(self, side: str, machine) -> None:
        if machine.wants_flush:
            self.channel.flush(side, self.now)
        if self.channel.queue_length(side) == 0:
            packet = machine.next_packet(self.now)
            if packet is not None:
                self.handed[side].append((self.now, packet))
                self.channel.send(side, packet, self.now)

    def run_until(self, t_end: float) -> None:
        while True:
            now = self.now
            while self._timers and self._timers[0][0] <= now:
                _, _, fn = heapq.heappop(self._timers)
                fn(now)
            for d in self.channel.deliver(now):
                data = d.data if self.tamper is None else self.tamper(d.to, d.data, now)
                if data is None:
                    continue
                if d.to == "b":
                    if not self.rov_down:
                        self._rov_events(self.rov.receive(data, now))
                else:
                    self._op_events(self.operator.receive(data, now))
            if not self.rov_down:
                self._rov_events(self.rov.tick(now))
                self.rov.update_status(self.vehicle.state())
            self._op_events(self.operator.tick(now))
            if not self.rov_down:
                self._feed("b", self.rov)
            self._feed("a", self.operator)
            if now >= t_end:
                break
            candidates = [t_end, now + self.step_s]
            nt = self.channel.next_time()
            if nt is not None:
                candidates.append(nt)
            if self._timers:
                candidates.append(self._timers[0][0])
            nxt = min(candidates)
            step = max(nxt, math.nextafter(now, math.inf))
            self.vehicle.step(step - now, self.rov)
            self.now = step


def new_key() -> bytes:
    return os.urandom(32)
