"""`rovlink console`, `rovlink replay` and `rovlink plot` as a user runs them:
real processes, real sockets.  The console and the ROV run as two programs
joined by UDP, the way they are deployed with a modem between them."""

from __future__ import annotations

import signal
import subprocess
import sys
import urllib.request

import pytest

from rovlink.link.transports.transport import free_udp_port

from ..helpers import free_tcp_port
from ..helpers import get_json as get
from ..helpers import wait_until_up as wait_for

ROVLINK = [sys.executable, "-m", "rovlink"]





def stop(proc: subprocess.Popen) -> tuple[int, str, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    return proc.returncode, out, err


def test_console_and_rov_as_two_programs_over_udp_then_replay_and_plot(tmp_path):
    console_port, rov_port = free_udp_port(), free_udp_port()
    page, scene = free_tcp_port(), free_tcp_port()
    record = tmp_path / "session.jsonl"
    key = tmp_path / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    # A fast link (no emulated modem between them): the real deployment's shape,
    # with both ends holding the same key (protocol version 2).
    rov = subprocess.Popen(ROVLINK + ["rov", "--link", f"udp://127.0.0.1:{rov_port}?peer=127.0.0.1:{console_port}",
                                      "--budget", "800", "--key", str(key)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    console = subprocess.Popen(
        ROVLINK + ["console", "--link", f"udp://127.0.0.1:{console_port}?peer=127.0.0.1:{rov_port}",
                   "--bitrate", "115200", "--delay", "0.01", "--port", str(page), "--viser-port", str(scene),
                   "--record", str(record), "--key", str(key)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    base = f"http://127.0.0.1:{page}"
    try:
        state = wait_for(lambda: (s := get(base + "/api/state"))["pose"].get("autopilot") and s, 60)
        assert state, "the console never heard the ROV's autopilot"
        assert wait_for(lambda: get(base + "/api/image")["images_completed"] >= 2, 60)
        image = get(base + "/api/image")
        assert image["settings"] is None  # the ROV's own defaults: the console cannot know them
        with urllib.request.urlopen(base + "/api/image/latest.debt", timeout=10) as r:
            assert len(r.read()) <= 800  # the ROV's --budget
        link = get(base + "/api/link")
        assert link["sent"] > 10 and link["reports"] > 10
    finally:
        console_rc, _, console_err = stop(console)
        rov_rc, _, rov_err = stop(rov)
    assert console_rc == 0 and "Traceback" not in console_err, console_err
    assert rov_rc == 0 and "Traceback" not in rov_err, rov_err

    # The recorded session plays back into a console of its own.
    page2, scene2 = free_tcp_port(), free_tcp_port()
    replay = subprocess.Popen(ROVLINK + ["replay", str(record), "--speed", "4", "--port", str(page2),
                                         "--viser-port", str(scene2)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    base2 = f"http://127.0.0.1:{page2}"
    try:
        assert wait_for(lambda: get(base2 + "/api/state")["replaying"], 60)
        assert wait_for(lambda: get(base2 + "/api/image")["images_completed"] >= 2, 60)
        assert get(base2 + "/api/state")["pose"]["autopilot"]
    finally:
        rc, _, err = stop(replay)
    assert rc == 0 and "Traceback" not in err, err

    out = subprocess.run(ROVLINK + ["plot", str(record), "--out", str(tmp_path / "plots")], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert len(out.stdout.split()) == 2


@pytest.mark.parametrize("args,words", [
    (["console", "--link", "carrier-pigeon://x"], "unknown transport"),
    (["replay", "/nonexistent/session.jsonl"], "no such file"),
    (["plot", "/nonexistent/session.jsonl"], "no such file"),
])
def test_console_commands_refuse_bad_input_in_one_line(args, words):
    out = subprocess.run(ROVLINK + args, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1
    assert words in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


@pytest.mark.parametrize("args", [["console"], ["demo", "--bitrate", "0"], ["demo", "--port", "0"],
                                  ["replay"], ["plot", "x", "--window", "-1"]])
def test_console_commands_refuse_wrong_arguments_with_status_2(args):
    out = subprocess.run(ROVLINK + args, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_the_console_needs_a_key_or_insecure(tmp_path):
    link = ["console", "--link", f"udp://127.0.0.1:{free_udp_port()}?peer=127.0.0.1:{free_udp_port()}",
            "--port", str(free_tcp_port()), "--viser-port", str(free_tcp_port()), "--no-record"]
    out = subprocess.run(ROVLINK + link, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "rovlink keygen" in out.stderr and len(out.stderr.strip().splitlines()) == 1
    key = tmp_path / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    key.chmod(0o644)
    out = subprocess.run(ROVLINK + link + ["--key", str(key)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "readable by others" in out.stderr, out.stderr
    out = subprocess.run(ROVLINK + link + ["--key", str(key), "--insecure"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "exclude each other" in out.stderr
    # A directory named as the key: said as such (not "chmod 600" on the directory).
    out = subprocess.run(ROVLINK + link + ["--key", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and out.stderr.strip().splitlines() == [
        f"rovlink console: error: {tmp_path} is a directory, not a key file: name the key file itself "
        f"(make one with rovlink keygen FILE)"], out.stderr


def test_a_missing_serial_port_is_said_once_and_nothing_is_left_running(tmp_path):
    key = tmp_path / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    console = ["console", "--port", str(free_tcp_port()), "--viser-port", str(free_tcp_port()), "--no-record"]
    port = "/dev/rovlink-no-such-port"
    for side, link in ((["rov", "--insecure"], f"serial://{port}"), (console + ["--insecure"], f"serial://{port}"),
                       (console + ["--key", str(key)], f"wlmodem://{port}?role=a")):
        out = subprocess.run(ROVLINK + side + ["--link", link], capture_output=True, text=True, timeout=60)
        assert out.returncode == 1, out.stderr
        lines = out.stderr.strip().splitlines()
        # One line, the port and why, "could not open" said once (it was said twice, after 5-6 s of retries).
        assert lines == [f"rovlink {side[0]}: error: {link}: could not open: no serial port {port} "
                         f"(is the modem's USB serial adapter plugged in?)"], lines
        assert "Task was destroyed" not in out.stderr
