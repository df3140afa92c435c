"""The whole system on one machine: simulated ArduSub, ROV node, emulated
channel and the operator's session, in one asyncio loop: the link thread's
(console/linkthread.py), never the loop of whoever starts the stack, so that
the web server that usually runs there cannot delay a poll.

Goals: `rovlink demo`, the console's tests and its benchmarks start the very
same parts a real deployment runs (the node speaks MAVLink to the simulator
over loopback UDP; the link bytes cross the channel emulator), with nothing
to set up.  `Stack.start()` brings them up, `Stack.stop()` takes them down in
reverse order.  Both are coroutines of the caller's loop; the parts run on
the link loop, and the caller reaches them (operator, node, channel, sim)
from its own thread as the operator allows: its methods are thread-safe.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from pathlib import Path

from rovlink.link.aio import run_channel
from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.messages import FAILSAFE_S, ImageSettings
from rovlink.link.transports.transport import Endpoint, inproc_pair
from rovlink.rov.autopilot import AutopilotBridge
from rovlink.rov.camera import open_camera
from rovlink.rov.node import RovNode
from rovlink.rov.seabed import Seabed
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.vehicle import VehicleState

from .linkthread import LinkThread
from .session.radio import Operator

log = logging.getLogger("rovlink.console.stack")


@dataclass
class StackConfig:
    bitrate_bps: float = 1900.0
    delay_s: float = 0.085
    ber: float = 7e-6
    seed: int = 0
    failsafe_s: float = FAILSAFE_S
    camera: str = "sim"
    record: str | Path | None = None
    channel_log: str | Path | None = None
    image_settings: ImageSettings = ImageSettings(mono=False, budget_bytes=2000)
    start_depth_m: float = 2.0
    # The link key (32 bytes): protocol version 2, every frame authenticated
    # (docs/PROTOCOL.md §8).  None: version 1.1, unauthenticated.
    key: bytes | None = None
    # The ROV's tracker for FOLLOW (docs/PROTOCOL.md §10, rov/follow.py): None, the
    # ROV refuses FOLLOW (and runs no camera thread: the tests' default).
    tracker: str | None = None
    # The simulated vehicle arms this long after it is asked (ARM answered IN_PROGRESS
    # meanwhile), as a vehicle finishing its checks does: 0, at once, as ArduSub.
    arm_delay_s: float = 0.0
    # The simulated seabed's PNG (its JSON beside it); None: the committed one.
    seabed: str | None = None
    # The ROV recognises objects on the seabed (rov/objects.py, docs/PROTOCOL.md §11; told over
    # version 2 only): as `rovlink rov` does by default.  Off in the tests' default stack.
    objects: bool = False


class VehicleSide:
    """The simulated ROV end: the ArduSub-like vehicle, the bridge to it, the
    camera, the ROV node, and the emulated channel in front of them.  The
    console's bytes come and go through `console_end` (an in-process endpoint
    for the tests, loopback UDP when `rovlink demo` runs this in a process of
    its own: console/vehicleside.py).  `start` and `stop` run on the loop the
    parts are to run on."""

    def __init__(self, config: StackConfig, console_end: Endpoint) -> None:
        self.config = config
        self.console_end = console_end
        self.sim = None
        self.bridge = None
        self.camera = None
        self.node = None
        self.channel: Channel | None = None
        self._endpoints: list[Endpoint] = []
        self._channel_log = None
        self.tasks: list[asyncio.Task] = []

    async def start(self) -> None:
        c = self.config
        seabed = Seabed.from_png(c.seabed) if c.seabed else Seabed.load()
        self.sim = SimulatedVehicle("udpin:127.0.0.1:0", initial_state=VehicleState(z_m=c.start_depth_m),
                                    floor_depth_m=seabed.depth_m, arm_delay_s=c.arm_delay_s).start()
        self.bridge = AutopilotBridge(self.sim.bridge_url).start()
        self.camera = open_camera(c.camera, seabed=seabed)
        chan_b, rov_end = inproc_pair("rov")
        self._endpoints = [self.console_end, chan_b, rov_end]
        for ep in self._endpoints:
            await ep.start()
        if c.channel_log:
            Path(c.channel_log).parent.mkdir(parents=True, exist_ok=True)
            self._channel_log = open(c.channel_log, "w", buffering=1)
        self.channel = Channel(LinkParams(bitrate_bps=c.bitrate_bps, delay_s=c.delay_s, ber=c.ber), seed=c.seed,
                               log=self._channel_log)
        geometry = None
        if c.objects:
            from rovlink.rov.objects import CameraGeometry

            geometry = CameraGeometry.of(self.camera)
        self.node = RovNode(rov_end, self.bridge, self.camera.capture, failsafe_s=c.failsafe_s,
                            default_settings=c.image_settings, key=c.key, follower=_follower(c.tracker),
                            objects=geometry)
        loop = asyncio.get_running_loop()
        self.tasks = [
            loop.create_task(run_channel(self.channel, self.console_end, chan_b), name="channel"),
            loop.create_task(self.node.run(), name="rov node"),
        ]

    async def stop(self) -> None:
        for task in reversed(self.tasks):
            task.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        self.tasks = []
        for ep in self._endpoints:
            await ep.close()
        if self.bridge:
            self.bridge.stop()
        if self.camera:
            self.camera.close()
        if self.sim:
            self.sim.stop()
        if self._channel_log:
            self._channel_log.close()


def _follower(tracker: str | None):
    if tracker is None:
        return None
    from rovlink.rov.follow import RoiFollower, TrackerMissing

    try:
        return RoiFollower(tracker)
    except TrackerMissing as exc:
        log.warning("the simulated ROV refuses FOLLOW: %s", exc)
        return None


class Stack:
    def __init__(self, config: StackConfig | None = None) -> None:
        self.config = config or StackConfig()
        self.vehicle: VehicleSide | None = None
        self.operator: Operator | None = None
        self._tasks: list[asyncio.Task] = []
        self._op_end: Endpoint | None = None
        self.link: LinkThread | None = None

    # The vehicle side's parts, for tests and benchmarks that reach into them.
    @property
    def sim(self):
        return self.vehicle.sim if self.vehicle else None

    @property
    def node(self):
        return self.vehicle.node if self.vehicle else None

    @property
    def channel(self) -> Channel | None:
        return self.vehicle.channel if self.vehicle else None

    async def start(self) -> Operator:
        self.link = LinkThread().start()
        try:
            await self.link.call(self._start_parts())
        except BaseException:
            await self.stop()
            raise
        return self.operator

    async def _start_parts(self) -> None:
        c = self.config
        op_end, chan_a = inproc_pair("operator")
        self._op_end = op_end
        self.vehicle = VehicleSide(c, chan_a)
        await self.vehicle.start()
        await op_end.start()
        self.operator = Operator(op_end, bitrate_bps=c.bitrate_bps, delay_s=c.delay_s, record=c.record,
                                 image_settings=c.image_settings)
        if c.key is not None:
            self.operator.authenticate(c.key)
        self._tasks = [asyncio.get_running_loop().create_task(self.operator.run(), name="operator")]

    async def stop(self) -> None:
        if self.link is not None:
            link, self.link = self.link, None
            await link.stop(self._stop_parts())
        else:
            await self._stop_parts()

    async def _stop_parts(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        if self.vehicle is not None:
            await self.vehicle.stop()
        if self._op_end is not None:
            await self._op_end.close()
        if self.operator:
            self.operator.close()

    async def __aenter__(self) -> "Stack":
        await self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()
