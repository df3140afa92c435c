"""The session's state has one description (console/session/state.py), which the
web API's response models reuse: every getter's dict fits its class, with no
key the class does not describe and none it requires missing, through a
session's life (starting, replies with pictures and orders, the link lost).

A simulated link on a fake clock (link.sim.SimLink), fed into the Operator as
its link loop feeds it."""

from __future__ import annotations

import random

import numpy as np
import pytest
from pydantic import BaseModel

from rovlink import debt
from rovlink.console.session import state as types
from rovlink.console.session.radio import Operator
from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.master import Master
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import Slave


def _fits(model: type[BaseModel], value, where: str) -> None:
    """`value` is exactly what `model` describes: validated, and no key it does not name."""
    model.model_validate(value)
    if model.model_config.get("extra") == "allow":
        return
    unknown = set(value) - set(model.model_fields)
    assert not unknown, f"{where}: keys {sorted(unknown)} are not described by {model.__name__}"
    for name, field in model.model_fields.items():
        inner = value.get(name)
        for candidate in getattr(field.annotation, "__args__", (field.annotation,)):
            if isinstance(candidate, type) and issubclass(candidate, BaseModel) and isinstance(inner, dict):
                _fits(candidate, inner, f"{where}.{name}")


def _check_all(op: Operator, where: str) -> None:
    _fits(types.PoseState, op.pose_state(), f"{where} pose_state")
    _fits(types.ImageState, op.image_state(), f"{where} image_state")
    _fits(types.LinkState, op.link_state(), f"{where} link_state")
    _fits(types.VelocityWish, op.wish_state(), f"{where} wish_state")
    for order in op.orders_state():
        _fits(types.OrderInfo, order, f"{where} order")
    for entry in op.log_entries():
        _fits(types.LogEntry, entry, f"{where} log")
    for past in op.image_history():
        assert isinstance(past.pop("stream"), bytes)
        _fits(types.PastImage, past, f"{where} past image")


@pytest.fixture
def session():
    rng = np.random.default_rng(3)
    picture = rng.integers(0, 255, (48, 64), dtype=np.uint8)
    streams = {}

    def source(img, settings):
        key = (img, settings)
        if key not in streams:
            streams[key] = debt.encode(picture, min(settings.budget_bytes, 600), mono=True)
        return streams[key]

    master = Master(rng=random.Random(1))
    sim: SimLink | None = None
    op = Operator(None, master=master, clock=lambda: sim.now if sim else 0.0)
    sim = SimLink(master, Slave(image_source=source), Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, ber=0.0),
                                                               seed=1),
                  on_master_event=lambda event, now: op.handle_events([event], now))
    yield op, sim
    op.close()


def test_every_getter_fits_the_type_the_api_describes(session):
    op, sim = session
    _check_all(op, "before any reply")
    op.set_pilot_in_force(True)
    op.set_velocity(0.3, 0.0, 0.0, -0.2)
    op.send_position(1.0, 2.0, 3.0, 45.0)
    op.set_image_settings(budget_bytes=500)
    op.arm(True)
    sim.run_until(20.0)
    assert op.last_reply is not None and op.image_state()["images_completed"] >= 1, op.log_entries()[-5:]
    assert op.image_history(), "no picture kept to look back at"
    assert op.pose_state()["velocity"] is not None
    _check_all(op, "replies flowing")

    sim.slave_down = True  # the ROV goes silent: the link is lost
    sim.run_until(30.0)
    assert op.link_state()["state"] == "lost" and op.link_state()["failsafe_inferred"]
    _check_all(op, "link lost")


def test_a_key_nobody_described_is_caught():
    # The check itself can fail: a getter that grew a key the API does not describe.
    with pytest.raises(AssertionError, match="not described"):
        _fits(types.VelocityWish, {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0, "surprise": 1}, "test")
