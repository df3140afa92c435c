"""The ROV node driven over UDP by the link master, against the simulated ArduSub.

Real parts throughout: UDP sockets for the link, pymavlink on both sides of
MAVLink, the DEBT encoder, the simulated camera.  The master runs with a fast
link model (no emulated narrow channel) so a test takes seconds.
"""

from __future__ import annotations

import asyncio
import random
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from rovlink import debt
from rovlink.link.aio import run_master
from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.radio.master import (
    ImageComplete,
    Master,
    OrderAcknowledged,
    OrderRejected,
    PoseReceived,
    StopConfirmed,
)
from rovlink.link.radio.messages import (
    ImageSettings,
    Mode,
    Poll,
    Position,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
)
from rovlink.link.transports.transport import free_udp_port
from rovlink.link.transports.urls import open_transport
from rovlink.rov.autopilot import AutopilotBridge
from rovlink.rov.camera import SimulatedCamera
from rovlink.rov.node import RovNode
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.vehicle import SubMode, VehicleState


class CountingBridge:
    """The real bridge, with a record of what the node asked of it."""

    def __init__(self, bridge):
        self._bridge = bridge
        self.calls = []

    def __getattr__(self, name):
        attr = getattr(self._bridge, name)
        if name in ("goto", "brake", "request_arm", "request_mode", "failsafe"):
            def record(*a, **kw):
                self.calls.append((name, a))
                return attr(*a, **kw)
            return record
        return attr

    def count(self, name):
        return sum(1 for n, _ in self.calls if n == name)


class Rig:
    def __init__(self, grab=None, failsafe_s=3.0):
        self.sim = SimulatedVehicle("udpin:127.0.0.1:0", initial_state=VehicleState(z_m=2.0)).start()
        self.bridge = CountingBridge(AutopilotBridge(self.sim.bridge_url).start())
        self.camera = SimulatedCamera()
        self.grab = grab or self.camera.capture
        self.failsafe_s = failsafe_s
        self.replies = []
        self.images = []
        self.acks = []
        self.rejected = []
        self.stops = []

    def on_master(self, events, now):
        for e in events:
            if isinstance(e, PoseReceived):
                self.replies.append((now, e.reply))
            elif isinstance(e, ImageComplete):
                self.images.append(e.data)
            elif isinstance(e, OrderAcknowledged):
                self.acks.append(e.order)
            elif isinstance(e, OrderRejected):
                self.rejected.append(e)
            elif isinstance(e, StopConfirmed):
                self.stops.append(e)

    async def start(self):
        pm, pr = free_udp_port(), free_udp_port()
        self.master_ep = open_transport(f"udp://127.0.0.1:{pm}?peer=127.0.0.1:{pr}")
        self.rov_ep = open_transport(f"udp://127.0.0.1:{pr}?peer=127.0.0.1:{pm}")
        await self.master_ep.start()
        await self.rov_ep.start()
        self.node = RovNode(self.rov_ep, self.bridge, self.grab, failsafe_s=self.failsafe_s)
        self.master = Master(bitrate_bps=200_000, delay_s=0.0, margin_s=0.3, rng=random.Random(1))
        self.node_task = asyncio.create_task(self.node.run())
        self.master_task = asyncio.create_task(run_master(self.master, self.master_ep, self.on_master))

    async def until(self, predicate, timeout_s):
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.05)
        return True

    async def close(self):
        for t in (self.master_task, self.node_task):
            t.cancel()
        await asyncio.gather(self.master_task, self.node_task, return_exceptions=True)
        await self.master_ep.close()
        await self.rov_ep.close()
        self.bridge.stop()
        self.sim.stop()


def run(coro, timeout=90):
    return asyncio.run(asyncio.wait_for(coro, timeout))


def now():
    return asyncio.get_running_loop().time()


def test_node_answers_polls_sends_roi_images_and_runs_orders_once():
    async def main():
        rig = Rig()
        await rig.start()
        try:
            # Odometry from the autopilot reaches the operator.
            # (HEARTBEAT comes first, LOCAL_POSITION_NED once the stream is asked for.)
            assert await rig.until(lambda: rig.replies and rig.replies[-1][1].autopilot
                                   and rig.replies[-1][1].position_valid, 15)
            reply = rig.replies[-1][1]
            assert reply.z_cm == pytest.approx(200, abs=30)

            # Images: the requested ROI, SHIFT and budget are honoured.
            roi = (100, 60, 220, 180)
            rig.master.send_order(ImageSettings(roi=roi, shift=6, mono=True, budget_bytes=900))
            assert await rig.until(lambda: ImageSettings(roi=roi, shift=6, mono=True, budget_bytes=900) in rig.acks, 10)
            n = len(rig.images)
            assert await rig.until(lambda: len(rig.images) >= n + 2, 20)
            stream = rig.images[-1]
            assert len(stream) <= 900
            header = debt.unpack_header(stream)
            assert tuple(header.roi) == roi and header.shift == 6
            picture = debt.decode(stream)
            assert picture.shape == (240, 320) and picture.dtype == np.uint8

            # Arm, then a position order: executed once, the vehicle goes there.
            rig.master.request_arm(True, now())
            assert await rig.until(lambda: rig.replies[-1][1].armed, 15)
            start = rig.sim.truth().state
            rig.master.send_order(Position(int(start.x_m * 100) + 200, int(start.y_m * 100), 200, 0))
            assert await rig.until(lambda: rig.replies[-1][1].mode == Mode.GUIDED, 15)
            assert await rig.until(lambda: abs(rig.sim.truth().state.x_m - (start.x_m + 2.0)) < 0.3, 30)
            # 1.1: STOP is not sequenced; it is confirmed by a reply to a STOP poll showing
            # HOLD and the brake, POS_HOLD with a position estimate (1.0: acknowledged, DEPTH_HOLD).
            brakes = rig.bridge.count("brake")
            assert brakes == 1  # the brake at start
            rig.master.send_order(Stop())
            assert await rig.until(lambda: rig.stops, 10)
            # POS_HOLD while the position estimate is valid, else DEPTH_HOLD: the bridge's choice at
            # that instant (a loaded machine can age the estimate past 1 s; tests/rov cover the choice).
            chosen = Mode.POS_HOLD if rig.node._brake_ticket.hold_mode == SubMode.POSHOLD else Mode.DEPTH_HOLD
            assert rig.stops[0].mode == chosen
            assert rig.replies[-1][1].mode == chosen
            assert Stop() not in rig.acks
            assert rig.bridge.count("goto") == 1
            assert rig.bridge.count("brake") - brakes == 1  # every STOP poll acts; the vehicle stayed braked
            # The arm request rode in many polls but reached the autopilot once.
            assert rig.bridge.count("request_arm") == 1
            assert rig.node.stats.images_encoded >= 2
        finally:
            await rig.close()

    run(main())


def test_failsafe_stops_the_vehicle_and_is_reported_when_polls_return():
    async def main():
        rig = Rig(failsafe_s=1.0)
        await rig.start()
        try:
            # 1.1: the first VELOCITY after start only sets the ARM/MODE reference, so the
            # pilot's requests go out once the link is up (the console's do the same).
            assert await rig.until(lambda: rig.replies and rig.replies[-1][1].autopilot, 15)
            rig.master.request_arm(True, now())
            rig.master.request_mode(Mode.MANUAL, now())
            assert await rig.until(lambda: rig.replies and rig.replies[-1][1].armed, 15)
            rig.master.set_velocity(100, 0, 0, 0, now())
            assert await rig.until(lambda: rig.sim.truth().pilot.x > 500, 10)
            # The operator goes silent.
            rig.master_task.cancel()
            await asyncio.gather(rig.master_task, return_exceptions=True)
            assert await rig.until(lambda: rig.node.slave.failsafe, 5)
            # 1.1: the failsafe brakes: POS_HOLD with a position estimate (1.0: ALT_HOLD, which coasts).
            assert await rig.until(lambda: rig.sim.truth().mode in (SubMode.POSHOLD, SubMode.ALT_HOLD), 10)
            assert await rig.until(lambda: abs(rig.sim.truth().pilot.x) < 50, 5)  # neutral
            assert rig.sim.truth().armed  # holding position, still armed
            # Polls return with the old wish still full ahead: the first reply says FAILSAFE,
            # then it clears, and HOLD keeps the vehicle still until the sticks are re-centred.
            rig.master_task = asyncio.create_task(run_master(rig.master, rig.master_ep, rig.on_master))
            assert await rig.until(lambda: any(r.failsafe for _, r in rig.replies), 10)
            assert await rig.until(lambda: not rig.replies[-1][1].failsafe, 10)
            assert not rig.node.slave.failsafe
            await asyncio.sleep(1.0)
            assert rig.replies[-1][1].hold and abs(rig.sim.truth().pilot.x) < 50
            rig.master.set_velocity(0, 0, 0, 0, now())
            assert await rig.until(lambda: not rig.replies[-1][1].hold, 5)
            rig.master.set_velocity(100, 0, 0, 0, now())
            assert await rig.until(lambda: rig.sim.truth().pilot.x > 500, 10)
            assert rig.bridge.calls.count(("failsafe", (True,))) == 1
            assert rig.bridge.calls.count(("failsafe", (False,))) == 1
        finally:
            await rig.close()

    run(main())


def test_replies_never_wait_for_the_encoder():
    gate = threading.Event()
    camera = SimulatedCamera()

    def slow_grab(pose):
        gate.wait(30)  # the encoder is stuck until the test lets it go
        return camera.capture(pose)

    async def main():
        rig = Rig(grab=slow_grab)
        await rig.start()
        try:
            assert await rig.until(lambda: len(rig.replies) >= 20, 20)
            assert not rig.images
            assert all(not r.has_trunk for _, r in rig.replies)  # answered, without image data
            gate.set()
            assert await rig.until(lambda: rig.images, 20)
        finally:
            gate.set()
            await rig.close()

    run(main())


def test_reserved_and_out_of_range_orders_are_answered_and_rejected():
    # 1.1 (§3): a reserved order or an invalid one-shot consumes its SEQ: ACK flips with
    # REJECTED, REASON 0 (1.0 answered and ignored them with ACK unchanged).  An invalid
    # VELOCITY is applied as neutral and rejects nothing (soft state has no REJECTED).
    async def main():
        rig = Rig()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(5)
        pr = free_udp_port()
        rig.rov_ep = open_transport(f"udp://127.0.0.1:{pr}?peer=127.0.0.1:{sock.getsockname()[1]}")
        await rig.rov_ep.start()
        rig.node = RovNode(rig.rov_ep, rig.bridge, rig.grab)
        task = asyncio.create_task(rig.node.run())
        try:
            polls = [
                (Poll(seq=1, order=ReservedOrder(9, b"junk")).encode(), (1, True, 0)),
                (bytes([0x81, 0x1F, 0xFF, 0x00, 0x80, 0, 0, 0]), (1, True, 0)),  # VELOCITY VX -128
                (bytes([0x02, 0x1F, 0xFF, 0x40]) + bytes(8), (0, True, 0)),  # POSITION BODY without RELATIVE
            ]
            loop = asyncio.get_running_loop()
            for payload, (ack, rejected, reason) in polls:
                sock.sendto(encode_frame(payload), ("127.0.0.1", pr))
                data = await loop.run_in_executor(None, sock.recv, 4096)
                reply = Reply.decode(FrameDecoder().feed(data)[0])
                assert (reply.ack, reply.rejected, reply.reason) == (ack, rejected, reason)
            assert rig.node.stats.orders_rejected == 2
            assert rig.bridge.count("goto") == 0
            assert rig.sim.truth().pilot.x == 0
        finally:
            sock.close()
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await rig.rov_ep.close()
            rig.bridge.stop()
            rig.sim.stop()

    run(main())


def test_position_while_disarmed_is_rejected_reason_1_and_never_reaches_the_autopilot():
    async def main():
        rig = Rig()
        await rig.start()
        try:
            assert await rig.until(lambda: rig.replies and rig.replies[-1][1].position_valid, 15)
            assert not rig.replies[-1][1].armed
            rig.master.send_order(Position(100, 0, 200, 0))
            assert await rig.until(lambda: rig.rejected, 10)
            assert rig.rejected[0].reason == 1 and rig.rejected[0].order == Position(100, 0, 200, 0)
            assert rig.bridge.count("goto") == 0
            assert rig.replies[-1][1].attitude_valid  # the autopilot's attitude is fresh
        finally:
            await rig.close()

    run(main())


def test_rovlink_rov_process_answers_polls_over_udp():
    pm, pr = free_udp_port(), free_udp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "rovlink", "rov", "--link", f"udp://127.0.0.1:{pr}?peer=127.0.0.1:{pm}",
         "--failsafe", "2", "--budget", "600", "--insecure"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    async def main():
        ep = open_transport(f"udp://127.0.0.1:{pm}?peer=127.0.0.1:{pr}")
        await ep.start()
        master = Master(bitrate_bps=200_000, delay_s=0.0, margin_s=0.3, rng=random.Random(2))
        got = {"replies": [], "images": []}

        def on(events, t):
            for e in events:
                if isinstance(e, PoseReceived):
                    got["replies"].append(e.reply)
                elif isinstance(e, ImageComplete):
                    got["images"].append(e.data)

        task = asyncio.create_task(run_master(master, ep, on))
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline and not (got["images"] and got["replies"][-1].autopilot):
            await asyncio.sleep(0.1)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await ep.close()
        return got

    try:
        got = run(main(), timeout=60)
    finally:
        proc.terminate()
        out, err = proc.communicate(timeout=15)
    assert got["replies"] and got["replies"][-1].autopilot
    assert got["images"] and len(got["images"][0]) <= 600
    assert debt.decode(got["images"][0]).shape[:2] == (240, 320)
    assert "Traceback" not in err, err


def test_bad_rov_arguments():
    out = subprocess.run([sys.executable, "-m", "rovlink", "rov", "--link", "bogus://x"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "unknown transport" in out.stderr
    out = subprocess.run([sys.executable, "-m", "rovlink", "rov", "--link", "udp://127.0.0.1:1?peer=127.0.0.1:2",
                          "--failsafe", "-1"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2


class FakeTicket:
    def __init__(self, status="pending", reject_reason=None):
        self.status, self.reject_reason, self.reason = status, reject_reason, ""

    @property
    def done(self):
        return self.status != "pending"


class FakeBridge:
    """Only what the node asks of an AutopilotBridge, with tickets the test resolves."""

    def __init__(self):
        from rovlink.rov.telemetry import AutopilotSnapshot

        self.snap = AutopilotSnapshot(armed=True, mode=Mode.MANUAL, autopilot_alive=True, position_valid=True,
                                      attitude_valid=True)
        self.calls = []
        self.tickets = []

    def _ticket(self, name, *a):
        self.calls.append(name)
        ticket = FakeTicket()
        self.tickets.append(ticket)
        return ticket

    def snapshot(self):
        return self.snap

    def set_velocity(self, *a):
        self.calls.append("set_velocity")

    def goto(self, *a, **kw):
        return self._ticket("goto")

    def brake(self):
        return self._ticket("brake")

    def request_arm(self, arm):
        return self._ticket("arm" if arm else "disarm")

    def request_mode(self, mode):
        return self._ticket(f"mode {mode}")

    def failsafe(self, active):
        self.calls.append(f"failsafe {active}")


class FakeEndpoint:
    max_frame = None


def fake_node():
    bridge = FakeBridge()
    node = RovNode(FakeEndpoint(), bridge, lambda snap: np.zeros((8, 8), np.uint8), encode=lambda *a, **k: b"x")
    node._refresh_status()
    return node, bridge


def exchange(node, poll, t):
    out = node.slave.receive(poll.encode(), t)
    node._on_events(out.events, t)
    return Reply.decode(FrameDecoder().feed(out.reply)[0]), out.events


@pytest.mark.parametrize("status,reject_reason,reason", [
    ("failed", 2, 2),  # the autopilot refused GUIDED
    ("failed", 1, 1),  # the bridge found it impossible
    ("cancelled", None, 1),  # another mode was requested, the bridge stopped
    ("accepted", None, None),
])
def test_the_node_reports_the_autopilots_answer_and_ack_flips_then(status, reject_reason, reason):
    node, bridge = fake_node()
    try:
        exchange(node, Poll(order=Velocity()), 0.0)
        reply, _ = exchange(node, Poll(seq=1, order=Position(100, 0, 100, 0)), 0.1)
        assert bridge.calls.count("goto") == 1 and reply.ack == 0  # waiting for the answer
        bridge.tickets[-1].status, bridge.tickets[-1].reject_reason = status, reject_reason
        node._check_order_tickets(time.monotonic())
        reply, _ = exchange(node, Poll(seq=1, order=Velocity()), 0.2)
        assert reply.ack == 1
        assert (reply.rejected, reply.reason) == ((False, 0) if reason is None else (True, reason))
        assert reply.attitude_valid and reply.position_valid
    finally:
        node._worker.shutdown(wait=True)


def test_the_node_brakes_at_start_on_stop_and_on_a_late_accept_of_an_abandoned_order():
    node, bridge = fake_node()
    try:
        node._on_events(node.slave.tick(0.0), 0.0)
        assert bridge.calls.count("brake") == 1  # at start
        bridge.tickets[-1].status = "accepted"
        exchange(node, Poll(order=Velocity()), 0.1)
        exchange(node, Poll(seq=1, order=Position(100, 0, 100, 0)), 0.2)
        goto = bridge.tickets[-1]
        reply, _ = exchange(node, Poll(seq=0, order=Stop()), 0.3)
        assert (reply.ack, reply.rejected, reply.reason, reply.hold) == (1, True, 1, True)
        assert bridge.calls.count("brake") == 2
        exchange(node, Poll(seq=1, order=Stop()), 0.4)  # repeated while the brake is pending: one brake
        assert bridge.calls.count("brake") == 2
        bridge.tickets[-1].status = "accepted"
        exchange(node, Poll(seq=1, order=Velocity()), 0.5)
        goto.status = "accepted"  # the autopilot took the abandoned order after all
        node._check_order_tickets(time.monotonic())
        assert bridge.calls.count("brake") == 3 and not node.slave.hold  # brake without HOLD
    finally:
        node._worker.shutdown(wait=True)


def test_arm_and_mode_reach_the_bridge_once_per_change_and_a_disarm_always():
    node, bridge = fake_node()
    try:
        exchange(node, Poll(order=Velocity(arm=1, mode=Mode.STABILIZE)), 0.0)  # reference only
        assert "arm" not in bridge.calls and not any(c.startswith("mode") for c in bridge.calls)
        exchange(node, Poll(order=Velocity()), 0.1)
        for t in (0.2, 0.3, 0.4):
            exchange(node, Poll(order=Velocity(mode=Mode.STABILIZE)), t)
        assert bridge.calls.count(f"mode {int(Mode.STABILIZE)}") == 1
        exchange(node, Poll(order=Velocity(arm=2)), 0.5)
        exchange(node, Poll(order=Velocity(arm=2)), 0.6)  # pending: not asked twice
        assert bridge.calls.count("disarm") == 1
        bridge.tickets[-1].status = "accepted"
        exchange(node, Poll(order=Velocity(arm=2)), 0.7)  # still armed says the autopilot: asked again
        assert bridge.calls.count("disarm") == 2
    finally:
        node._worker.shutdown(wait=True)
