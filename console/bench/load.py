"""Web load against a running console: does any of it reach the link?

`rovlink demo` runs as its own process (the console's link loop in its own
thread, the web server in another loop).  This process takes control over
the REST API and steers (a velocity wish every 0.25 s), first with no other
traffic, then under load: `readers` WebSocket clients reading telemetry
(those past the console's cap are refused and try again every second) and
`uploads` parallel clients each streaming a 200 MB request body, again as
soon as the server answers.  The demo records its session and its channel's
events; afterwards:

- poll interval: from the recording's transmitted polls, median and p95 of
  each phase (the target: p95 under 0.6 s while steering, under load);
- replies lost: polls after which the next poll went out with no reply in
  between, against the frames the channel itself dropped, corrupted or
  collided (the channel log): every lost reply must be one of those.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from .child import die_with_parent, end_child

UPLOAD_BYTES = 200 * 1024 * 1024


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _request(url: str, method: str = "GET", body: dict | None = None, client: str | None = None, timeout=10.0):
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    if client:
        req.add_header("X-Rovlink-Client", client)
    with urllib.request.urlopen(req, timeout=timeout) as r:
        return json.loads(r.read() or b"null")


def _session_time(base: str) -> float:
    return float(_request(f"{base}/api/state")["link"]["t"])


async def _steer(base: str, client: str, stop: asyncio.Event) -> int:
    sent, k = 0, 0
    while not stop.is_set():
        k += 1
        wish = {"vx": 0.3 if (k // 8) % 2 == 0 else -0.3, "vy": 0.0, "vz": 0.0, "vyaw": 0.1}
        try:
            await asyncio.to_thread(_request, f"{base}/api/orders/velocity", "POST", wish, client)
            sent += 1
        except OSError:
            pass
        try:
            await asyncio.wait_for(stop.wait(), 0.25)
        except TimeoutError:
            pass
    return sent


async def _reader(ws_url: str, stop: asyncio.Event, counts: dict) -> None:
    import websockets

    while not stop.is_set():
        try:
            async with websockets.connect(ws_url, open_timeout=10, max_size=None) as ws:
                while not stop.is_set():
                    try:
                        await asyncio.wait_for(ws.recv(), 1.0)
                        counts["messages"] += 1
                    except TimeoutError:
                        continue
        except websockets.exceptions.ConnectionClosed as exc:
            counts["refused" if exc.rcvd is not None and exc.rcvd.code == 1013 else "closed"] += 1
        except (OSError, TimeoutError, websockets.exceptions.InvalidHandshake):
            counts["failed"] += 1
        try:
            await asyncio.wait_for(stop.wait(), 1.0)
        except TimeoutError:
            pass


async def _uploader(port: int, stop: asyncio.Event, counts: dict) -> None:
    """Start a 200 MB upload, stream it until the server answers or drops the
    connection, and start again at once."""
    chunk = b"\0" * 65536
    while not stop.is_set():
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            counts["failed"] += 1
            await asyncio.sleep(0.2)
            continue
        counts["attempts"] += 1
        writer.write((f"POST /api/orders/velocity HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                      f"Content-Type: application/json\r\nContent-Length: {UPLOAD_BYTES}\r\n\r\n").encode())
        sent = 0
        answer = asyncio.ensure_future(reader.read(64))
        try:
            while sent < UPLOAD_BYTES and not stop.is_set() and not answer.done() and not writer.is_closing():
                writer.write(chunk)
                await writer.drain()
                sent += len(chunk)
            head = await asyncio.wait_for(answer, 10)
            status = head[9:12].decode(errors="replace") if head.startswith(b"HTTP/") else "none"
            counts[f"status_{status}"] = counts.get(f"status_{status}", 0) + 1
        except (OSError, TimeoutError):
            counts["reset"] += 1  # the server closed the connection on the body it will not read
        finally:
            answer.cancel()
            writer.close()


def _polls(recording: Path) -> tuple[list[float], list[float]]:
    tx, rx = [], []
    with open(recording, encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            if rec.get("k") == "tx":
                tx.append(rec["t"])
            elif rec.get("k") == "rx":
                rx.append(rec["t"])
    return tx, rx


def _lost_cycles(tx: list[float], rx: list[float]) -> int:
    """Polls followed by the next poll with no reply bytes in between."""
    lost, j = 0, 0
    for a, b in zip(tx, tx[1:]):
        while j < len(rx) and rx[j] < a:
            j += 1
        if not (j < len(rx) and rx[j] < b):
            lost += 1
    return lost


def _channel_losses(channel_log: Path) -> dict:
    counts: dict = {}
    with open(channel_log, encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            if rec["ev"] in ("loss", "corrupt", "collision", "drop"):
                key = f"{rec['dir']} {rec['ev']}"
                counts[key] = counts.get(key, 0) + 1
    return counts


def _intervals(tx: list[float], start: float, end: float) -> dict:
    times = [t for t in tx if start <= t <= end]
    gaps = sorted(b - a for a, b in zip(times, times[1:]))
    if not gaps:
        return {"polls": len(times), "median_s": None, "p95_s": None, "max_s": None}
    return {"polls": len(times), "median_s": round(statistics.median(gaps), 3),
            "p95_s": round(gaps[min(len(gaps) - 1, int(0.95 * len(gaps)))], 3), "max_s": round(gaps[-1], 3)}


def measure_load(seconds: float, readers: int, uploads: int, ber: float) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="rovlink-bench-load-"))
    record = folder / "session.jsonl"
    port, viser_port = _free_port(), _free_port()
    demo = subprocess.Popen(
        [sys.executable, "-m", "rovlink", "demo", "--port", str(port), "--viser-port", str(viser_port),
         "--ber", str(ber), "--record", str(record)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=folder,
        env={**os.environ, "PYTHONUNBUFFERED": "1"}, preexec_fn=die_with_parent)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 300  # a first run compiles the codec first
        while True:
            try:
                if _request(f"{base}/api/state")["pose"]["received"] is not None:
                    break
            except (OSError, KeyError, TypeError, ValueError):
                pass
            if demo.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"rovlink demo did not come up: {demo.stderr.read()[-500:] if demo.poll() is not None else 'timeout'}")
            time.sleep(0.5)
        client = _request(f"{base}/api/control/take", "POST", {"name": "bench"})["client_id"]
        reader_counts = {"messages": 0, "refused": 0, "closed": 0, "failed": 0}
        upload_counts = {"attempts": 0, "reset": 0, "failed": 0}

        async def phases() -> dict:
            marks = {}
            stop_steer = asyncio.Event()
            steer = asyncio.create_task(_steer(base, client, stop_steer))
            await asyncio.sleep(3.0)  # the master settles on the steering SIZE
            marks["idle_start"] = await asyncio.to_thread(_session_time, base)
            await asyncio.sleep(seconds)
            marks["idle_end"] = marks["load_start"] = await asyncio.to_thread(_session_time, base)
            stop_load = asyncio.Event()
            ws_url = f"ws://127.0.0.1:{port}/ws"
            load = [asyncio.create_task(_reader(ws_url, stop_load, reader_counts)) for _ in range(readers)]
            load += [asyncio.create_task(_uploader(port, stop_load, upload_counts)) for _ in range(uploads)]
            await asyncio.sleep(seconds)
            marks["load_end"] = await asyncio.to_thread(_session_time, base)
            stop_load.set()
            await asyncio.gather(*load, return_exceptions=True)
            stop_steer.set()
            marks["steering_posts"] = await steer
            return marks

        marks = asyncio.run(phases())
    finally:
        end_child(demo, first=signal.SIGINT)
    tx, rx = _polls(record)
    # Both counts cover the whole run: the channel log has a clock of its own.
    channel = _channel_losses(Path(str(record).replace(".jsonl", "") + ".channel.jsonl"))
    lost = _lost_cycles(tx, rx)
    channel_lost = sum(channel.values())
    return {
        "seconds_per_phase": seconds, "readers": readers, "uploads": uploads, "ber": ber,
        "idle": _intervals(tx, marks["idle_start"], marks["idle_end"]),
        "load": _intervals(tx, marks["load_start"], marks["load_end"]),
        "replies_lost": lost, "channel_losses": channel, "channel_lost_total": channel_lost,
        "replies_lost_not_by_channel": max(0, lost - channel_lost),
        "websocket": reader_counts, "uploads_result": upload_counts, "steering_posts": marks["steering_posts"],
    }
