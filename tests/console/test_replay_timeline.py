"""The replay timeline (issue 13): a recorded session played with pause, seek
and speed, through the controller, its REST API and the page's bar in
headless Chromium.  Going back shows exactly what playing to that moment
shows; a replay says REPLAY, never LINK LOST.

One short recording (protocol 2, small images, the vehicle driving) is made
once for the module with the whole in-process stack."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import socket
import threading
import time

import pytest

from rovlink.console.replaycontrol import MAX_SPEED, ReplayController, controller_of
from rovlink.console.session.radio import Operator
from rovlink.console.stack import Stack, StackConfig
from rovlink.link.radio.messages import ImageSettings

from ..helpers import CHROMIUM, CHROMIUM_ARGS, local_test_client, needs_chromium
from .conftest import wait_for


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A session of ~8 s: armed, driving and turning, three images shown (then pictures
    off, so that the session is long enough for the timeline's tests whatever the link's
    picture rate)."""
    path = tmp_path_factory.mktemp("replay") / "session.jsonl"

    async def session() -> None:
        config = StackConfig(bitrate_bps=19200, delay_s=0.02, ber=0.0, key=bytes(range(32)), record=path,
                             image_settings=ImageSettings(mono=True, budget_bytes=500))
        async with Stack(config) as stack:
            op = stack.operator
            deadline = time.monotonic() + 90
            while not (op.last_reply is not None and op.last_reply.autopilot):
                assert time.monotonic() < deadline, "the ROV never answered"
                await asyncio.sleep(0.05)
            op.arm(True)
            op.set_velocity(0.8, 0.0, 0.0, 0.3)
            started = time.monotonic()
            while op.image_state()["images_completed"] < 3:
                assert time.monotonic() < deadline, "no images came"
                await asyncio.sleep(0.05)
            op.set_image_settings(budget_bytes=0)
            await asyncio.sleep(max(0.3, 6.0 - (time.monotonic() - started)))
            op.set_velocity(0.0, 0.0, 0.0, 0.0)
            await asyncio.sleep(0.3)

    asyncio.run(session())
    return path


def image_times(path) -> list[float]:
    """Session times of the images completed in the recording."""
    with open(path, encoding="utf-8") as f:
        return [r["t"] for r in map(json.loads, f) if r.get("k") == "image"]


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def shown(op: Operator) -> dict:
    """What a page or the scene shows of a replayed session."""
    state = op.state()
    return {
        "now": op.now(),
        "image": {k: state["image"][k] for k in ("img", "serial", "images_completed", "received_bytes",
                                                  "total_bytes", "complete", "capture")},
        "received": state["pose"]["received"],
        "predicted": state["pose"]["predicted"],
        "armed": state["pose"].get("armed"),
        "trail": list(op.history.trail),
        "commanded": list(op.history.commanded),
        "link_events": list(op.history.link_events),
        "wish": state["velocity_wish"],
        "orders": [(o["id"], o["kind"], o["state"]) for o in state["orders"]],
        "link": (state["link"]["state"], state["link"]["version"]),
        "images_kept": [(e["n"], e["img"], e["bytes"]) for e in op.image_history()],
    }


def same(a: dict, b: dict) -> bool:
    """Equal, but for the last bits of the clock (a played clock is a sum of steps)."""
    clocked = ("now", "predicted")
    assert {k: v for k, v in a.items() if k not in clocked} == {k: v for k, v in b.items() if k not in clocked}
    assert a["now"] == pytest.approx(b["now"], abs=1e-9)
    assert a["predicted"] == pytest.approx(b["predicted"], abs=1e-6)
    return True


def play_to(controller: ReplayController, clock: FakeClock, t: float, step_s: float = 0.05) -> None:
    """Plain playing, as the player thread does, until session time t."""
    while controller.position < t - 1e-9:
        clock.now += min(step_s, (t - controller.position) / controller.speed)
        controller.advance()


# ----------------------------------------------------------------------
# The controller
# ----------------------------------------------------------------------


def test_seeking_back_shows_what_playing_to_that_moment_shows(recording):
    first, second, third = image_times(recording)[:3]
    moment = (second + third) / 2  # two images shown, the third on its way

    clock = FakeClock()
    played = Operator(None)
    player = ReplayController(played, recording, monotonic=clock, speed=2.0)
    play_to(player, clock, moment)
    player.pause()
    expected = shown(played)
    assert expected["image"]["images_completed"] == 2 and expected["received"] is not None
    assert expected["now"] == pytest.approx(moment)

    seeker_op = Operator(None)
    seeker = ReplayController(seeker_op, recording, monotonic=FakeClock(), paused=True)
    events: list[str] = []
    seeker_op.subscribe(lambda topic, payload: events.append(topic))
    seeker.seek(seeker.duration)
    at_end = shown(seeker_op)
    assert at_end["image"]["images_completed"] >= 3 and at_end["trail"] != expected["trail"]

    events.clear()
    seeker.seek(moment)
    assert same(shown(seeker_op), expected)
    # The same Operator, its subscribers kept, told once rather than flooded.
    assert controller_of(seeker_op) is seeker
    assert {"pose", "image"} <= set(events) and len(events) < 10, events
    assert seeker_op.log_entries()[-1]["text"].startswith("replay: at ")

    # Straight there from the start, and on from there, the same again.
    direct_op = Operator(None)
    direct = ReplayController(direct_op, recording, monotonic=FakeClock(), paused=True)
    direct.seek(moment)
    assert same(shown(direct_op), expected)
    later = (third + player.duration) / 2
    player.resume()
    play_to(player, clock, later)
    player.pause()
    seeker.seek(later)
    assert shown(played)["image"]["images_completed"] == 3
    assert same(shown(seeker_op), shown(played))


def test_pause_stops_the_session_clock_and_what_is_fed(recording):
    clock = FakeClock()
    op = Operator(None)
    controller = ReplayController(op, recording, monotonic=clock)
    play_to(controller, clock, 2.0)
    controller.pause()
    counts, trail = dict(controller.counts), list(op.history.trail)
    clock.now += 30.0
    assert controller.advance() is None
    assert controller.position == pytest.approx(2.0) and op.now() == pytest.approx(2.0)
    assert controller.counts == counts and list(op.history.trail) == trail
    state = controller.state()
    assert state["paused"] is True and state["t"] == pytest.approx(2.0)

    controller.resume()
    clock.now += 1.0
    controller.advance()
    assert controller.position == pytest.approx(3.0)
    assert controller.counts["replies"] > counts["replies"]


def test_speed_scales_the_session_clock_from_where_it_is(recording):
    clock = FakeClock()
    controller = ReplayController(Operator(None), recording, monotonic=clock)
    clock.now += 1.0
    controller.set_speed(4.0)
    clock.now += 0.5
    assert controller.position == pytest.approx(1.0 + 4 * 0.5)
    controller.set_speed(0.25)
    clock.now += 2.0
    assert controller.position == pytest.approx(3.0 + 0.25 * 2.0)
    # The player sleeps until the next record is due on the new clock.
    wait = controller.advance()
    assert wait is not None and wait <= (controller._times[controller._index] - controller.position) / 0.25 + 1e-9


def test_the_end_pauses_and_play_starts_it_again(recording):
    clock = FakeClock()
    op = Operator(None)
    done = []
    controller = ReplayController(op, recording, monotonic=clock, speed=8.0, on_done=done.append)
    play_to(controller, clock, controller.duration - 0.5, step_s=0.5)
    assert not controller.ended
    clock.now += 1.0  # past the end
    controller.advance()
    assert controller.ended and controller.paused and done and done[0]["replies"] > 50
    clock.now += 10
    assert controller.position == pytest.approx(controller.duration)
    assert any(e["text"].startswith("replay finished") for e in op.log_entries())
    assert op.link_state()["state"] == "replay" and op.link_state()["version"] == "2"

    controller.resume()
    assert not controller.ended and not controller.paused
    assert controller.position == pytest.approx(0.0, abs=1e-6)
    assert op.image_state()["images_completed"] == 0 and op.last_reply is None


def test_bad_speeds_and_times_are_refused(recording):
    controller = ReplayController(Operator(None), recording, paused=True)
    for speed in (0, -1, 0.05, MAX_SPEED * 2, math.nan, math.inf):
        with pytest.raises(ValueError, match="speed"):
            controller.set_speed(speed)
    for t in (-0.1, controller.duration + 1, math.nan):
        with pytest.raises(ValueError, match="session time"):
            controller.seek(t)
    assert controller.speed == 1.0 and controller.position == 0.0


# ----------------------------------------------------------------------
# The REST API
# ----------------------------------------------------------------------


@pytest.fixture
def replay_app(recording):
    from rovlink.console.web.app import create_app

    op = Operator(None)
    controller = ReplayController(op, recording, paused=True).start()
    with local_test_client(create_app(op)) as client:
        yield client, controller, op
    controller.close()


def test_the_api_pauses_seeks_and_changes_speed(replay_app, recording):
    client, controller, op = replay_app
    state = client.get("/api/replay").json()
    assert state["available"] is True and state["paused"] is True and state["t"] == 0.0
    assert state["duration"] == pytest.approx(controller.duration, abs=1e-3) and 1.0 in state["speeds"]

    second = image_times(recording)[1]
    r = client.post("/api/replay/seek", json={"t": second + 0.01})
    assert r.status_code == 200 and r.json()["t"] == pytest.approx(second + 0.01, abs=1e-3)
    assert client.get("/api/state").json()["image"]["images_completed"] == 2
    r = client.post("/api/replay/seek", json={"t": 0.5})  # back
    assert r.json()["t"] == pytest.approx(0.5) and r.json()["seeks"] == state["seeks"] + 2
    assert client.get("/api/state").json()["image"]["images_completed"] == 0

    assert client.post("/api/replay/speed", json={"speed": 2}).json()["speed"] == 2.0
    r = client.post("/api/replay/resume").json()
    assert r["paused"] is False
    assert wait_for(lambda: client.get("/api/replay").json()["t"] > 1.0, 5)
    assert client.get("/api/state").json()["link"]["state"] == "replay"
    r = client.post("/api/replay/pause").json()
    assert r["paused"] is True
    time.sleep(0.3)
    assert client.get("/api/replay").json()["t"] == r["t"]
    # A replay has no ROV: orders are still refused, the timeline needed no control.
    assert client.post("/api/orders/arm", json={"armed": True}).status_code == 409


def test_bad_values_are_422_with_a_message(replay_app):
    client, controller, _ = replay_app
    for path, body in [("seek", {"t": -1}), ("seek", {"t": controller.duration + 5}), ("seek", {"t": "3"}),
                       ("seek", {}), ("seek", {"t": 1, "extra": 2}), ("speed", {"speed": 0}),
                       ("speed", {"speed": 1000}), ("speed", {"speed": True})]:
        r = client.post(f"/api/replay/{path}", json=body)
        assert r.status_code == 422, (path, body, r.text)
        assert r.json()["message"], (path, body)
    r = client.post("/api/replay/speed", content=b'{"speed": NaN}', headers={"Content-Type": "application/json"})
    assert r.status_code == 422
    assert client.get("/api/replay").json()["t"] == 0.0 and controller.speed == 1.0


def test_a_live_console_has_no_timeline():
    from rovlink.console.web.app import create_app

    with local_test_client(create_app(Operator(None))) as client:
        assert client.get("/api/replay").json()["available"] is False
        for path, body in [("pause", None), ("resume", None), ("seek", {"t": 1}), ("speed", {"speed": 2})]:
            r = client.post(f"/api/replay/{path}", json=body)
            assert r.status_code == 409 and "not replaying" in r.json()["message"], path


def test_the_timeline_keeps_the_consoles_access_rules(recording):
    from rovlink.console.web.app import create_app
    from rovlink.console.web.guard import AccessPolicy

    op = Operator(None)
    controller = ReplayController(op, recording, paused=True)
    app = create_app(op, policy=AccessPolicy("0.0.0.0", token="s3cret-token"))
    with local_test_client(app) as client:
        assert client.post("/api/replay/resume").status_code == 401
        assert client.get("/api/replay").status_code == 401
        r = client.post("/api/replay/resume", headers={"Origin": "http://evil.example"},
                        params={"token": "s3cret-token"})
        assert r.status_code == 403 and controller.paused
        assert client.post("/api/replay/resume", params={"token": "s3cret-token"}).json()["paused"] is False


# ----------------------------------------------------------------------
# The page
# ----------------------------------------------------------------------


@contextlib.contextmanager
def served(app):
    """`app` served by uvicorn on a free loopback port, in a thread's loop."""
    from rovlink.console.web.app import serve

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    url = f"http://127.0.0.1:{sock.getsockname()[1]}"
    holder: dict = {}
    started = threading.Event()

    async def main() -> None:
        holder["loop"], holder["task"] = asyncio.get_running_loop(), asyncio.current_task()
        started.set()
        await serve(app, sock=sock)

    def run() -> None:
        with contextlib.suppress(asyncio.CancelledError):
            asyncio.run(main())

    thread = threading.Thread(target=run, name="replay page", daemon=True)
    thread.start()
    assert started.wait(10)
    try:
        yield url
    finally:
        holder["loop"].call_soon_threadsafe(holder["task"].cancel)
        thread.join(10)


@pytest.mark.browser
@needs_chromium
def test_the_bar_pauses_seeks_and_says_replay(recording):
    from playwright.sync_api import sync_playwright

    from rovlink.console.web.app import create_app

    op = Operator(None)
    controller = ReplayController(op, recording, paused=True).start()
    errors: list[str] = []
    try:
        with served(create_app(op)) as url, sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1366, "height": 768})
                page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
                page.on("console", lambda m: errors.append(f"console: {m.text}") if m.type == "error" else None)
                page.goto(url + "/?scene=off")
                page.wait_for_selector("#replay-bar", state="visible", timeout=20000)
                page.wait_for_function("document.body.dataset.link === 'replay'", timeout=20000)
                assert page.text_content("#link-banner-title") == "REPLAY"
                assert page.is_visible("#link-banner")
                assert "LINK LOST" not in page.inner_text("body")

                assert page.get_attribute("#replay-bar", "data-state") == "paused"
                assert page.text_content("#replay-time").startswith("0:00.0 / 0:0")
                # No picture yet, and the page says why instead of showing an empty frame.
                page.wait_for_function("document.getElementById('no-image-done').textContent === "
                                       "'no picture in the recording yet'")
                assert page.is_visible("#no-image-done") and page.is_hidden("#image-done")
                page.evaluate("window.jumps = 0; addEventListener('rovlink:replay-jump', () => { window.jumps += 1; })")

                # Playing: the time runs.
                page.click("#replay-play")
                page.wait_for_function("document.getElementById('replay-bar').dataset.state === 'playing'")
                assert not controller.paused
                page.wait_for_function("+document.getElementById('replay-bar').dataset.t > 1.0")
                assert controller.position > 1.0

                # Paused: it stands still, here and on the server.
                page.click("#replay-play")
                page.wait_for_function("document.getElementById('replay-bar').dataset.state === 'paused'")
                assert controller.paused
                held = page.text_content("#replay-time")
                at = controller.position
                time.sleep(1.2)
                assert page.text_content("#replay-time") == held and controller.position == at

                # Dragging the slider seeks when it is let go, back or forward.
                box = page.locator("#replay-slider").bounding_box()
                y = box["y"] + box["height"] / 2
                page.mouse.move(box["x"] + box["width"] * 0.2, y)
                page.mouse.down()
                page.mouse.move(box["x"] + box["width"] * 0.5, y, steps=5)
                assert controller.position == at  # not while held
                page.mouse.move(box["x"] + box["width"] * 0.8, y, steps=5)
                page.mouse.up()
                target = 0.8 * controller.duration
                assert wait_for(lambda: abs(controller.position - target) < 0.1 * controller.duration, 5), \
                    (controller.position, target)
                page.wait_for_function(f"Math.abs(+document.getElementById('replay-bar').dataset.t - "
                                       f"{controller.position}) < 0.05")
                assert controller.paused and op.now() == pytest.approx(controller.position)
                page.wait_for_function("window.jumps === 1")  # the page is told its past was rewritten

                page.select_option("#replay-speed", "2")
                assert wait_for(lambda: controller.speed == 2.0, 5)
                page.click("#replay-play")
                page.wait_for_function("document.getElementById('replay-bar').dataset.state !== 'paused'")
                assert wait_for(lambda: controller.ended, 15)
                page.wait_for_function("document.getElementById('replay-bar').dataset.state === 'ended'")
                assert page.text_content("#link-banner-title") == "REPLAY"
                assert "Again" in page.text_content("#replay-play")

                # Played again from the start.
                page.click("#replay-play")
                page.wait_for_function("document.getElementById('replay-bar').dataset.state === 'playing'")
                assert not controller.ended and controller.position < 0.5 * controller.duration
                page.wait_for_function("window.jumps === 2")
            finally:
                browser.close()
    finally:
        controller.close()
    assert not errors, errors


# ----------------------------------------------------------------------
# The command
# ----------------------------------------------------------------------


def post(url: str, body: dict | None = None) -> dict:
    import urllib.request

    request = urllib.request.Request(url, data=json.dumps(body or {}).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as r:
        return json.loads(r.read())


def test_rovlink_replay_serves_the_timeline(recording):
    import signal
    import subprocess
    import sys

    from ..helpers import free_tcp_port, get_json, wait_until_up

    rovlink = [sys.executable, "-m", "rovlink", "replay"]
    out = subprocess.run(rovlink + [str(recording), "--speed", "100"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "0.1..64" in out.stderr and len(out.stderr.strip().splitlines()) == 1

    port = free_tcp_port()
    proc = subprocess.Popen(rovlink + [str(recording), "--paused", "--port", str(port),
                                       "--viser-port", str(free_tcp_port())],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}/api/replay"
    try:
        state = wait_until_up(lambda: get_json(base), 60)
        assert state, proc.stderr.read() if proc.poll() is not None else "no answer"
        assert state["available"] and state["paused"] and state["t"] == 0.0
        assert post(base + "/seek", {"t": 2.0})["t"] == 2.0
        assert post(base + "/resume")["paused"] is False
        assert wait_until_up(lambda: get_json(base)["t"] > 2.5, 10)
        assert get_json(f"http://127.0.0.1:{port}/api/link")["state"] == "replay"
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        stdout, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0
    assert "timeline" in stdout and "paused" in stdout


def test_damaged_records_are_skipped_and_counted(recording, tmp_path):
    lines = recording.read_text(encoding="utf-8").splitlines()
    middle = len(lines) // 2
    damaged = [json.dumps({"k": "rx", "t": json.loads(lines[middle])["t"], "hex": "not hex"}),
               json.dumps({"k": "wish", "t": json.loads(lines[middle])["t"]}),
               json.dumps({"k": "reply", "t": json.loads(lines[middle])["t"], "hex": 42})]
    path = tmp_path / "damaged.jsonl"
    path.write_text("\n".join(lines[:middle] + damaged + lines[middle:]) + "\n", encoding="utf-8")

    clean_op, damaged_op = Operator(None), Operator(None)
    clean = ReplayController(clean_op, recording, monotonic=FakeClock(), paused=True)
    controller = ReplayController(damaged_op, path, monotonic=FakeClock(), paused=True)
    controller.seek(controller.duration)
    clean.seek(clean.duration)
    assert controller.counts["damaged"] == 3
    assert shown(damaged_op) == shown(clean_op)
    controller.seek(0.0)  # and back
    assert controller.counts["damaged"] == 0
