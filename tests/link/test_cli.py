"""The rovlink command as a user runs it: real processes, real sockets."""

import json
import signal
import socket
import subprocess
import sys
import time

import pytest

from rovlink.link.radio.frame import FrameDecoder, encode_frame
from rovlink.link.transports.transport import free_udp_port

ROVLINK = [sys.executable, "-m", "rovlink"]


def rovlink(*args, timeout=120):
    return subprocess.run(ROVLINK + list(args), capture_output=True, text=True, timeout=timeout)


def test_help_lists_the_commands():
    out = rovlink("--help")
    assert out.returncode == 0
    assert "channel" in out.stdout and "bench" in out.stdout


@pytest.mark.parametrize("args", [["channel", "--help"], ["bench", "--help"], ["bench", "link", "--help"]])
def test_every_command_explains_itself(args):
    out = rovlink(*args)
    assert out.returncode == 0 and "usage:" in out.stdout and len(out.stdout) > 100


@pytest.mark.parametrize("args", [
    ["nosuchcommand"],
    ["channel"],
    ["channel", "--a", "udp://127.0.0.1:1", "--b", "udp://127.0.0.1:2", "--bitrate", "fast"],
    ["channel", "--a", "udp://127.0.0.1:1", "--b", "udp://127.0.0.1:2", "--ber", "2"],
    ["bench", "link", "--duration", "x"],
])
def test_wrong_arguments_give_one_line_and_status_2(args):
    out = rovlink(*args)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "error:" in out.stderr


def test_bad_transport_url_is_a_one_line_error():
    out = rovlink("channel", "--a", "tcp://x:1", "--b", "udp://127.0.0.1:9")
    assert out.returncode == 1
    assert out.stderr.strip().splitlines() == [
        "rovlink channel: error: unknown transport 'tcp' in 'tcp://x:1': use udp://, serial://, wlmodem:// or inproc://"]


def _channel(tmp_path, *options: str):
    """`rovlink channel` between two UDP users bound on loopback, logging to
    tmp_path/channel.jsonl: (ports, a_user, b_user, log, proc).  Ports: a_user,
    the channel's a end, its b end, b_user."""
    ports = [free_udp_port() for _ in range(4)]
    users = []
    for port in (ports[0], ports[3]):
        user = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        user.bind(("127.0.0.1", port))
        users.append(user)
    log = tmp_path / "channel.jsonl"
    proc = subprocess.Popen(
        ROVLINK + ["channel", "--a", f"udp://127.0.0.1:{ports[1]}?peer=127.0.0.1:{ports[0]}",
                   "--b", f"udp://127.0.0.1:{ports[2]}?peer=127.0.0.1:{ports[3]}",
                   *options, "--log", str(log), "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return ports, users[0], users[1], log, proc


def test_channel_process_carries_frames_with_delay_and_logs(tmp_path):
    ports, a_user, b_user, log, proc = _channel(tmp_path, "--bitrate", "1900", "--delay", "0.085")
    try:
        banner = proc.stderr.readline()  # printed once both ends are bound (a fixed sleep flaked under load)
        assert banner.startswith("channel: "), banner
        frame = encode_frame(bytes(range(20)))  # 24 bytes: 101 ms on the air + 85 ms
        a_user.settimeout(10)
        b_user.settimeout(10)
        t0 = time.monotonic()
        a_user.sendto(frame, ("127.0.0.1", ports[1]))
        data, _ = b_user.recvfrom(4096)
        elapsed = time.monotonic() - t0
        assert FrameDecoder().feed(data) == [bytes(range(20))]
        assert elapsed >= 0.18  # serialisation + intrinsic delay really applied
        reply = encode_frame(b"back")
        b_user.sendto(reply, ("127.0.0.1", ports[2]))
        data, _ = a_user.recvfrom(4096)
        assert data == reply
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        a_user.close()
        b_user.close()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    events = [json.loads(line) for line in log.read_text().splitlines()]
    kinds = [(e["ev"], e["dir"]) for e in events]
    assert ("tx", "a>b") in kinds and ("rx", "a>b") in kinds and ("rx", "b>a") in kinds
    assert all("t" in e for e in events)


def test_channel_takes_its_queue_by_name(tmp_path):
    """--queue is the transmit queue: a 30-byte queue drops the second of two 24-byte
    frames sent at once.  The options reach the model by name (a field added to it, the
    loss's burst, once took --queue's place)."""
    ports, a_user, b_user, log, proc = _channel(tmp_path, "--queue", "30")
    try:
        assert proc.stderr.readline().startswith("channel: ")
        frame = encode_frame(bytes(range(20)))
        a_user.sendto(frame, ("127.0.0.1", ports[1]))
        a_user.sendto(frame, ("127.0.0.1", ports[1]))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and '"drop"' not in (log.read_text() if log.exists() else ""):
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=10)
        a_user.close()
        b_user.close()
    events = [json.loads(line) for line in log.read_text().splitlines()]
    assert [e["why"] for e in events if e["ev"] == "drop"] == ["queue full"]
    assert sum(1 for e in events if e["ev"] == "tx") == 1


def test_the_bench_pilot_centres_the_sticks_after_a_failsafe_and_steers_on():
    """`rovlink bench link`'s steering pilot never centres the sticks by itself, but
    does when a reply shows the ROV holding (after a failsafe), as the page asks:
    the ROV takes no other wish until then.  So wishes keep arriving after every
    failsafe, and the hour's figures under loss are an hour's, not its first minutes'."""
    from rovlink.link.bench import run_session

    for mode in ("rovlink", "rovlink v2"):
        sess = run_session(mode, 0.0, True, 600.0, 3, loss=0.2, burst=3.0)
        assert sess.failsafes >= 3
        for fs in sess.failsafe_at:
            assert any(fs < t <= fs + 20.0 for t in sess.wish_arrived_at), (mode, fs)


def test_bench_link_prints_a_table_and_json(tmp_path):
    out = rovlink("bench", "link", "--duration", "120", "--loss-duration", "300", "--out", str(tmp_path / "plots"))
    assert out.returncode == 0, out.stderr
    assert "idle img s" in out.stdout and "steering under loss" in out.stdout and "targets:" in out.stdout
    assert "bounds (what no version 2 of this shape can beat" in out.stdout
    # The distributions as plots in the output folder (real PNG files).
    for name in ("picture_time_steering.png", "poll_interval_steering.png"):
        assert (tmp_path / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = rovlink("bench", "link", "--duration", "120", "--loss-duration", "300", "--out", "", "--json")
    doc = json.loads(out.stdout)
    assert {r["mode"] for r in doc["results"]} == {"rovlink", "rovlink v2", "paper"}
    assert {r["ber"] for r in doc["results"]} == {0.0, 7e-6, 1e-4, 1e-3}
    by = {(r["mode"], r["ber"]): r for r in doc["results"]}
    for mode in ("rovlink", "rovlink v2"):
        # Never faster than physics: 2000 bytes at 1900 bit/s.
        assert by[(mode, 0.0)]["idle_image_s_median"] >= by[(mode, 0.0)]["floor_s"]
    # Wishes reach the ROV (a pilot starts from centred sticks, as HOLD at start asks).
    assert all(by[(mode, 7e-6)]["wish_latency_s_median"] is not None for mode in ("rovlink", "rovlink v2"))
    # Issue 23: version 2 delivers pictures faster than 1.1 while steering, and its
    # first 500 bytes (already a picture) sooner than the whole.
    v2, v11 = by[("rovlink v2", 7e-6)], by[("rovlink", 7e-6)]
    assert v2["steering_image_s_median"] < v11["steering_image_s_median"]
    assert v2["steering_first_500B_s_median"] < v2["steering_image_s_median"]
    # Under loss: both versions, every loss and both channel kinds, counted.
    assert {(r["mode"], r["loss"], r["burst"]) for r in doc["under_loss"]} == {
        (m, loss, burst) for m in ("rovlink", "rovlink v2") for loss in (0.05, 0.1, 0.2) for burst in (1.0, 3.0)}
    assert all(r["failsafes_per_hour"] >= 0 and r["pictures_per_hour"] > 0 for r in doc["under_loss"])
    # The floors printed under the two figures version 2 misses (docs/PROTOCOL.md §8, §8.1):
    # never above what version 2 measures (a floor above a measurement would be wrong),
    # and computed from the wire: 9 replies of at most 239 picture bytes for 2000 bytes.
    idle = doc["bounds"]["v2_idle_2000B"]
    assert (idle["replies"], idle["picture_bytes_per_reply"], idle["picture_bytes_needed_for_one_fewer"]) == (9, 239, 250)
    assert v2["floor_s"] < idle["seconds"] <= by[("rovlink v2", 0.0)]["idle_image_s_median"]
    fs = doc["bounds"]["v2_failsafes_at_5%_bursts"]
    assert fs["polls_in_failsafe_time"] == 11 and 0 < fs["expected_per_hour"]
    assert "v2_steering_2000B_le_22s" in doc["targets"] and "v2_failsafes_le_1x_v1.1_at_10%_bursts" in doc["targets"]
    assert all(isinstance(t["met"], bool) for t in doc["targets"].values())


def test_keygen_writes_a_private_key_once(tmp_path):
    import stat

    from rovlink.link.radio.auth import read_key_file

    path = tmp_path / "link.key"
    out = subprocess.run(ROVLINK + ["keygen", str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    key = read_key_file(str(path))
    again = subprocess.run(ROVLINK + ["keygen", str(path)], capture_output=True, text=True, timeout=60)
    assert again.returncode == 1 and "never overwritten" in again.stderr and len(again.stderr.splitlines()) == 1
    assert read_key_file(str(path)) == key
    other = tmp_path / "other.key"
    subprocess.run(ROVLINK + ["keygen", str(other)], check=True, capture_output=True, timeout=60)
    assert read_key_file(str(other)) != key


def test_bench_link_acoustic_prints_a_table_and_json():
    out = rovlink("bench", "link", "--profile", "acoustic", "--duration", "240")
    assert out.returncode == 0, out.stderr
    assert "STOP@ROV p50" in out.stdout and "targets:" in out.stdout and "status age under loss" in out.stdout
    out = rovlink("bench", "link", "--profile", "acoustic", "--duration", "240", "--json")
    doc = json.loads(out.stdout)
    by = {(r["loss"], r["burst"]): r for r in doc["results"]}
    assert set(by) == {(0.0, 1.0), (0.1, 1.0), (0.3, 1.0), (0.1, 3.0), (0.3, 3.0)}
    for r in doc["results"]:  # every row: STOPs pressed and carried, thumbnails verified, no failsafe
        assert r["stops"] > 0 and r["stop_at_rov_s_p50"] >= 1.5 and r["alone_thumbnails"] > 0 and r["failsafes"] == 0
    # A 200-byte thumbnail is 30 packets: at one a second it cannot come sooner than 30 s.
    assert by[(0.0, 1.0)]["alone_thumbnail_s_p50"] >= 30.0
    assert {"stop_at_rov_p95_le_3s_at_10%", "thumbnail_200B_alone_p95_le_60s_at_10%",
            "status_never_older_than_10s_at_0%_thumbnails_alone"} <= set(doc["targets"])
    assert all(isinstance(t["met"], bool) for t in doc["targets"].values())
    assert set(doc["status_age_under_loss"]) == {"10% independent", "30% independent", "10% bursts", "30% bursts"}
