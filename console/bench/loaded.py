"""The console on a busy machine (`rovlink bench console`'s loaded row, issue 33).

The vehicle side alone on one core: `rovlink rov` and `rovlink channel` (1900 bit/s,
85 ms, BER 0: a channel that loses nothing).  On the other core: `rovlink console`
(version 2, every frame authenticated), two CPU-bound processes, a client reading
/api/state and /api/pose 40 times a second, and headless Chromium showing the
page with its 3-D scene.  For `minutes`, after a warm-up: the polls whose reply
did not come in time (on this channel every one of them is a reply late, starved of
CPU), the link's LINK LOST and the ROV's FAILSAFE alerts.  The target: at most
0.5 % of polls, none, none.

`link_thread=True` runs the console with `--link-thread`: the link in a thread of
the console's own process, as before issue 33, for the before-and-after figures.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time

from rovlink.link.transports.transport import free_udp_port

from .child import die_with_parent, end_child
from .page import CHROMIUM, CHROMIUM_ARGS
from .pilot import _free_port, _get

WARM_UP_S = 20.0
READS_PER_S = 40.0


def _nice(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[16])
    except (OSError, ValueError, IndexError):
        return None


def _scheduling(pid: int) -> str | None:
    """The process's scheduling policy by its name (SCHED_RR, SCHED_OTHER, ...)."""
    try:
        policy = os.sched_getscheduler(pid)
    except OSError:
        return None
    return next((name for name in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
                 if getattr(os, name, None) == policy), str(policy))


def _pinned(cores: set[int], nice: int = 0):
    def pin() -> None:
        die_with_parent()
        os.sched_setaffinity(0, cores)
        if nice:
            try:
                os.nice(nice)
            except OSError:  # not allowed to raise it: the row says the nice it ran at
                pass

    return pin


def _cores() -> tuple[set[int], set[int]]:
    """The vehicle side's core and the console's (both all cores on a 1-core machine)."""
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        return set(cores), set(cores)
    return {cores[0]}, set(cores[1:])


def measure_loaded(minutes: float = 10.0, *, link_thread: bool = False, burners: int = 2,
                   channel_nice: int = 0) -> dict:
    from playwright.sync_api import sync_playwright

    vehicle_core, console_core = _cores()
    workdir = tempfile.mkdtemp(prefix="rovlink-bench-loaded-")
    key = os.path.join(workdir, "link.key")
    subprocess.run([sys.executable, "-m", "rovlink", "keygen", key], check=True, capture_output=True)
    console_udp, chan_a, chan_b, rov_udp = (free_udp_port() for _ in range(4))
    http, viser = _free_port(), _free_port()
    base = f"http://127.0.0.1:{http}"
    channel_log = os.path.join(workdir, "channel.jsonl")  # whose time a late reply spent
    procs: list[subprocess.Popen] = []
    logs = []

    def start(name: str, argv: list[str], cores: set[int], nice: int = 0) -> subprocess.Popen:
        log = open(os.path.join(workdir, f"{name}.log"), "w")
        logs.append(log)
        p = subprocess.Popen(argv, cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
                             preexec_fn=_pinned(cores, nice))
        procs.append(p)
        return p

    py = [sys.executable, "-m", "rovlink"]
    own_affinity = os.sched_getaffinity(0)
    stop = threading.Event()
    reads = [0, 0]  # made, failed
    samples: list[str] = []
    try:
        start("rov", py + ["rov", "--key", key, "--link", f"udp://127.0.0.1:{rov_udp}?peer=127.0.0.1:{chan_b}"],
              vehicle_core)
        channel = start("channel", py + ["channel", "--a", f"udp://127.0.0.1:{chan_a}?peer=127.0.0.1:{console_udp}",
                               "--b", f"udp://127.0.0.1:{chan_b}?peer=127.0.0.1:{rov_udp}", "--bitrate", "1900",
                               "--delay", "0.085", "--ber", "0", "--quiet", "--log", channel_log],
              vehicle_core, channel_nice)
        console = start("console", py + ["console", "--key", key, "--no-record", "--port", str(http), "--viser-port",
                                         str(viser), "--link", f"udp://127.0.0.1:{console_udp}?peer=127.0.0.1:{chan_a}"]
                        + (["--link-thread"] if link_thread else []), console_core)
        for i in range(burners):
            start(f"burner{i}", [sys.executable, "-c", "while True: pass"], console_core)
        deadline = time.monotonic() + 300
        while True:
            try:
                if _get(base + "/api/link")["state"] == "up":
                    break
            except OSError:
                pass
            if console.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("the console did not come up: "
                                   + open(os.path.join(workdir, "console.log")).read()[-2000:])
            time.sleep(0.5)

        def read() -> None:
            period = 1.0 / READS_PER_S
            n = 0
            next_at = time.monotonic()
            while not stop.is_set():
                try:
                    _get(base + ("/api/state" if n % 2 == 0 else "/api/pose"))
                except OSError:
                    reads[1] += 1
                reads[0] += 1
                n += 1
                next_at += period
                time.sleep(max(0.0, next_at - time.monotonic()))

        def sample() -> None:
            while not stop.wait(0.5):
                try:
                    samples.append(_get(base + "/api/link")["state"])
                except OSError:
                    samples.append("unreachable")

        # This process (the reader, and Chromium it starts) on the console's core too.
        os.sched_setaffinity(0, console_core)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1366, "height": 768})
                page.goto(base)
                page.wait_for_function("document.body.dataset.configured === '1'", timeout=120000)
                threads = [threading.Thread(target=read, daemon=True), threading.Thread(target=sample, daemon=True)]
                for t in threads:
                    t.start()
                time.sleep(WARM_UP_S)
                before = _get(base + "/api/link")
                started_wall, started = time.time(), time.monotonic()
                time.sleep(minutes * 60)
                ended = time.monotonic()
                after = _get(base + "/api/link")
                log = _get(base + "/api/log")
            finally:
                stop.set()
                browser.close()
        link_pid = after.get("link_process_pid")
        link_nice = _nice(link_pid) if link_pid else None
        channel_nice_seen = _nice(channel.pid)
        link_scheduling = _scheduling(link_pid) if link_pid else None
    finally:
        stop.set()
        os.sched_setaffinity(0, own_affinity)
        for p in reversed(procs):
            end_child(p)
        for f in logs:
            f.close()
    polls = after["sent"] - before["sent"]
    lost = after["reports_lost"] - before["reports_lost"]
    alerts = [e for e in log if e["level"] == "alert" and e["wall"] >= started_wall]
    vehicle_side = vehicle_side_delays(channel_log, started, ended)
    return {
        "minutes": minutes,
        "link": "thread of the console's process" if link_thread else "process of its own",
        "link_process_pid": link_pid,
        # Its scheduling priority (link/process.py raises it where the system allows).
        "link_process_nice": link_nice,
        "link_process_scheduling": link_scheduling,  # SCHED_RR where the system allows it
        "console_pid": console.pid,
        "polls": polls,
        "replies_not_in_time": lost,
        "late_percent": round(100.0 * lost / max(1, polls), 3),
        "late_replies_v2": after.get("late_replies", 0) - before.get("late_replies", 0),
        "link_lost_alerts": sum(1 for e in alerts if e["text"].startswith("LINK LOST")),
        "failsafe_alerts": sum(1 for e in alerts if "FAILSAFE" in e["text"]),
        "state_percent": {s: round(100.0 * samples.count(s) / max(1, len(samples)), 2)
                          for s in ("up", "degraded", "lost")},
        "api_reads": reads[0], "api_reads_failed": reads[1],
        "cores": {"vehicle": sorted(vehicle_core), "console": sorted(console_core)},
        "burners": burners,
        # The channel emulator's nice (an outside run raised it above the vehicle side's).
        "channel_nice": channel_nice_seen,
        "vehicle_side": vehicle_side,
    }


def vehicle_side_delays(channel_log: str, since: float, until: float = float("inf"), *,
                        bitrate_bps: float = 1900.0, delay_s: float = 0.085) -> dict:
    """Whose time a late reply spent, from the channel's own log (`rovlink channel --log`,
    its clock CLOCK_MONOTONIC as this process's): each poll the console sent between
    `since` and `until`, paired with the ROV's reply to it (the ROV's next frame before
    the console's next one).  The ROV's turnaround runs from the poll handed to it to
    its reply taken in; the channel's lateness is how long after their arrival it handed
    either on.  A reply is late on the vehicle side when it was handed back to the console
    later than the master's timeout allows (docs/PROTOCOL.md §5: both frames' air time,
    twice the delay, and the margin, 0.15 s, or 0.05 s after a lost reply, counted here
    both ways) after the poll entered the channel; every other reply the console counts
    late was late on the console's side (its link process sent the poll after its timer
    started, or read the reply after its deadline)."""
    import json

    polls: list[dict] = []
    current: dict | None = None
    with open(channel_log) as f:
        for line in f:
            try:
                r = json.loads(line)
            except ValueError:
                continue  # a line cut short as the channel ended
            ev, direction = r.get("ev"), r.get("dir")
            if ev == "tx" and direction == "a>b":
                current = {"t": r["t"], "air_s": 8.0 * r["bytes"] / bitrate_bps, "late": 0.0} \
                    if since <= r["t"] < until else None
                if current is not None:
                    polls.append(current)
            elif current is None:
                continue
            elif ev == "rx" and direction == "a>b" and "handed" not in current:
                current["handed"] = r["t"] + r.get("late_s", 0.0)
                current["late"] = r.get("late_s", 0.0)
            elif ev == "tx" and direction == "b>a" and "handed" in current and "reply" not in current:
                current["reply"], current["due_back"] = r["t"], r["arrival"]
                current["air_s"] += 8.0 * r["bytes"] / bitrate_bps
            elif ev == "rx" and direction == "b>a" and "reply" in current and "back" not in current:
                current["back"] = r["t"] + r.get("late_s", 0.0)
                current["late"] = max(current["late"], r.get("late_s", 0.0))
    turnaround = sorted(p["reply"] - p["handed"] for p in polls if "reply" in p)

    def ms(q: float) -> float | None:
        return round(1000 * turnaround[min(len(turnaround) - 1, int(q * len(turnaround)))], 1) if turnaround else None

    def late(margin_s: float) -> dict:
        out = {"rov": 0, "channel": 0}
        for p in polls:
            if "back" in p and p["back"] - p["t"] > p["air_s"] + 2 * delay_s + margin_s:
                out["rov" if p["reply"] - p["handed"] > p["late"] else "channel"] += 1
        return out

    # The console's next poll entered the channel before this one's reply was back, and
    # sooner than the shortest timeout (0.05 s margin) after this one: this poll left the
    # console later than the time its timer ran from (the console's side).
    timer_ahead = sum(1 for p, q in zip(polls, polls[1:]) if "due_back" in p and q["t"] < p["due_back"]
                      and q["t"] - p["t"] < p["air_s"] + 2 * delay_s + 0.05)
    return {"polls": len(polls), "unanswered": sum(1 for p in polls if "back" not in p),
            "console_poll_left_after_its_timer_started": timer_ahead,
            "rov_turnaround_ms": {"p50": ms(0.5), "p99": ms(0.99), "max": ms(1.0)},
            "rov_over_50ms": sum(1 for t in turnaround if t > 0.05),
            "channel_late_over_50ms": sum(1 for p in polls if p["late"] > 0.05),
            "late_on_vehicle_side": late(0.15), "late_on_vehicle_side_outage_margin": late(0.05)}


def loaded_lines(rows: list[dict]) -> list[str]:
    from rovlink.bench import format_table

    return [f"the console on a busy machine: rovlink rov and rovlink channel (1900 bit/s, 85 ms, BER 0) on core "
            f"{rows[0]['cores']['vehicle']}; on {rows[0]['cores']['console']} rovlink console, {rows[0]['burners']} "
            f"CPU-bound processes, {READS_PER_S:g} API reads a second and headless Chromium showing the page; "
            f"{rows[0]['minutes']:g} min after {WARM_UP_S:g} s of warm-up; the channel at nice {rows[0].get('channel_nice')}",
            format_table(["the link runs in", "priority", "polls", "not answered in time", "%", "LINK LOST",
                          "FAILSAFE", "up / degraded / lost %"], [
                [r["link"], (f"nice {r.get('link_process_nice')}, {r.get('link_process_scheduling')}"
                             if r.get("link_process_pid") else "—"),
                 r["polls"], r["replies_not_in_time"], r["late_percent"], r["link_lost_alerts"],
                 r["failsafe_alerts"],
                 f"{r['state_percent']['up']} / {r['state_percent']['degraded']} / {r['state_percent']['lost']}"]
                for r in rows]),
            "whose time (the channel's log): the ROV's turnaround from a poll handed to it to its reply, and the "
            "channel's own lateness",
            format_table(["the link runs in", "polls", "unanswered", "ROV p50 / p99 / max ms", "ROV > 50 ms",
                          "channel late > 50 ms", "late by ROV / channel (0.05 s margin)",
                          "console's poll left after its timer"], [
                [r["link"], v["polls"], v["unanswered"],
                 " / ".join(str(v["rov_turnaround_ms"][k]) for k in ("p50", "p99", "max")),
                 v["rov_over_50ms"], v["channel_late_over_50ms"],
                 f"{v['late_on_vehicle_side']['rov']} / {v['late_on_vehicle_side']['channel']} "
                 f"({v['late_on_vehicle_side_outage_margin']['rov']} / "
                 f"{v['late_on_vehicle_side_outage_margin']['channel']})",
                 v["console_poll_left_after_its_timer_started"]]
                for r in rows if (v := r.get("vehicle_side"))])]


def loaded_target(r: dict) -> dict:
    ok = r["late_percent"] <= 0.5 and r["link_lost_alerts"] == 0 and r["failsafe_alerts"] == 0
    return {"late_percent": r["late_percent"], "limit_percent": 0.5, "link_lost_alerts": r["link_lost_alerts"],
            "failsafe_alerts": r["failsafe_alerts"], "minutes": r["minutes"],
            "met": ok if r["minutes"] >= 10 and r["burners"] >= 2 else None}
