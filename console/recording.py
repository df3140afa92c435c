"""Recorded sessions: reading them, playing them back, plotting them.

A recording (written by `console.session.recorder.Recorder`) is JSON lines, each with
`k` (kind) and `t` (session seconds): "meta" first, then "tx"/"rx" frames as
hex, "wish" velocity changes, "order" and "order_state", "pose", "image".

Playback (`replaycontrol`: a timeline to pause, seek and change speed) needs no ROV: the
recorded polls and replies go through `link.replay.ReplyReplayer` (the link's own
decoder and `Reply`, the image trunks taken by the master's own rules), and the
resulting events are handed to the session, which shows them as if live (its scene
and web page work unchanged).  An acoustic recording keeps what its session took
(statuses, thumbnails, orders, log lines), fed back as it was.

Plots: Fig. 4 style time-lapse of the link (each frame a bar from its send to
its arrival, per direction, height its size; images completed marked) and a
Fig. 5 style comparison of the velocity commanded on the console with the
velocity the ROV received (carried by polls that were answered).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from rovlink.link.radio.frame import MAX_FRAME, FrameDecoder
from rovlink.link.radio.messages import Velocity
from rovlink.link.radio.secure import poll_sent_from_frame
from rovlink.link.units import wish_fractions, wish_of


class RecordingError(ValueError):
    """A file that is not a readable rovlink recording."""


def read_records(path: str | Path) -> Iterator[dict]:
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    with open(path, encoding="utf-8") as f:
        first = True
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                if first:
                    raise RecordingError(f"{path}: not a rovlink recording (line {lineno} is not JSON)") from None
                continue  # a line cut short when the session was killed
            if first:
                if record.get("k") != "meta":
                    raise RecordingError(f"{path}: not a rovlink recording (no meta record first)")
                if record.get("profile", "radio") not in ("radio", "acoustic"):
                    raise RecordingError(f"{path}: a recording of a link this rovlink does not know "
                                         f"({record.get('profile')!r}); it replays radio and acoustic sessions")
                first = False
            yield record
    if first:
        raise RecordingError(f"{path}: empty recording")


# ---------------------------------------------------------------------------
# Plots
# ---------------------------------------------------------------------------


@dataclass
class Series:
    bitrate_bps: float
    delay_s: float
    frames: list[tuple[float, str, int]]  # (t, "tx"/"rx", bytes)
    commanded: list[tuple[float, tuple[float, ...]]]  # (t, (vx, vy, vz, vyaw)) in fractions
    received: list[tuple[float, tuple[float, ...]]]
    images: list[tuple[float, float]]  # (completed at, seconds it took)
    duration_s: float
    profile: str = "radio"
    # The acoustic link: (t, x_m, y_m, z_m, yaw_deg) of every status, and the go-tos sent (t, x_m, y_m, z_m).
    statuses: list = None
    targets: list = None


def is_acoustic(path: str | Path) -> bool:
    return next(iter(read_records(path))).get("profile") == "acoustic"


def _acoustic_series(records: list[dict]) -> Series:
    """An acoustic session (docs/PROTOCOL.md §9): 8-byte packets at the modem's
    64 bit/s, the statuses' poses, the go-tos and the thumbnails completed."""
    frames, images, statuses, targets = [], [], [], []
    for r in records[1:]:
        k, t = r.get("k"), float(r.get("t", 0.0))
        if k in ("tx", "rx"):
            frames.append((t, k, len(bytes.fromhex(r["hex"]))))
        elif k == "status" and r.get("position_valid"):
            statuses.append((t, r["x_m"], r["y_m"], r["z_m"], r["yaw_deg"]))
        elif k == "order" and r.get("kind") == "POSITION" and not r.get("relative"):
            targets.append((t, r["x_m"], r["y_m"], r["z_m"]))
        elif k == "thumb" and r.get("complete"):
            images.append((t, 0.0))
    duration = max([f[0] for f in frames] + [s[0] for s in statuses] + [0.0])
    return Series(64.0, 0.0, frames, [], [], images, duration, "acoustic", statuses, targets)


def series(path: str | Path) -> Series:
    records = list(read_records(path))
    meta = records[0]
    if meta.get("profile") == "acoustic":
        return _acoustic_series(records)
    bitrate = float(meta.get("bitrate_bps", 1900.0))
    delay = float(meta.get("delay_s", 0.085))
    frames, received, images = [], [], []
    commanded: list = [(0.0, (0.0, 0.0, 0.0, 0.0))]  # the wish is neutral until the pilot moves
    last_poll = None
    last_wish = None  # the last VELOCITY's wish (a version 2 NONE poll repeats it)
    replies = FrameDecoder()
    version = "1.1"  # "2" once the recording says every frame is authenticated
    for r in records[1:]:
        k, t = r.get("k"), float(r.get("t", 0.0))
        if k == "link":
            version = "2" if r.get("version") == 2 else "1.1"
        elif k == "tx":
            data = bytes.fromhex(r["hex"])
            frames.append((t, "tx", len(data)))
            # The poll as the master made it (version 2 may leave parts out of the frame, §8.1),
            # read by the link's own code; a HELLO carries none.
            sent = poll_sent_from_frame(data, t, version=version,
                                        poll=bytes.fromhex(r["poll"]) if "poll" in r else None)
            order = None if sent is None or sent.poll is None else sent.poll.order
            if isinstance(order, Velocity):
                wish = wish_of(order)
            elif order is not None and version == "2" and order.code == 0:
                wish = last_wish  # version 2: a NONE poll repeats the last wish the ROV took (§8.1)
            else:
                wish = None
            last_wish = wish
            last_poll = (t + 8 * len(data) / bitrate + delay, wish) if wish is not None else None
        elif k == "rx":
            data = bytes.fromhex(r["hex"])
            frames.append((t, "rx", len(data)))
            if version == "1.1" and replies.feed(data) and last_poll is not None:
                received.append(last_poll)
                last_poll = None
        elif k == "reply" and version == "2" and not r.get("sync"):
            # Version 2: an authentic, timely reply (its frame has no CRC to find it by, §8.1).
            if last_poll is not None:
                received.append(last_poll)
                last_poll = None
        elif k == "wish":
            commanded.append((t, wish_fractions(r["v"])))
        elif k == "image":
            images.append((t, float(r.get("seconds", 0.0))))
    duration = max([f[0] for f in frames] + [0.0])
    return Series(bitrate, delay, frames, commanded, received, images, duration)


def plot(path: str | Path, out_dir: str | Path, *, window_s: float | None = None) -> list[Path]:
    """Write fig4_link_timelapse.png and fig5_velocity.png; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = series(path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_end = s.duration_s if window_s is None else min(s.duration_s, window_s)

    fig, ax = plt.subplots(figsize=(12, 3.6))
    for t, kind, n in s.frames:
        if t > t_end:
            break
        length = 8 * n / s.bitrate_bps
        if kind == "tx":  # operator -> ROV: drawn from send to arrival
            ax.broken_barh([(t, length + s.delay_s)], (1.0, n / MAX_FRAME * 0.8), color="tab:blue", alpha=0.8)
        else:  # ROV -> operator: drawn ending at its arrival
            ax.broken_barh([(t - length - s.delay_s, length + s.delay_s)], (0.0, n / MAX_FRAME * 0.8), color="tab:orange",
                           alpha=0.8)
    for t, took in s.images:
        if t <= t_end:
            ax.axvline(t, color="tab:green", lw=1, ls="--")
            ax.axvline(t - took, color="tab:gray", lw=0.8, ls=":")
    ax.set_yticks([0.4, 1.4], ["ROV → operator", "operator → ROV"])
    ax.set_xlabel("session time (s)")
    ax.set_xlim(0, max(t_end, 1.0))
    ax.set_title(f"Link time-lapse ({s.bitrate_bps:g} bit/s, {s.delay_s * 1000:g} ms delay): bar height = frame "
                 f"size; green = image received, grey = image requested")
    fig.tight_layout()
    fig4 = out / "fig4_link_timelapse.png"
    fig.savefig(fig4, dpi=110)
    plt.close(fig)

    if s.profile == "acoustic":
        return [fig4, _acoustic_fig5(s, out, t_end, plt)]
    fig, axes = plt.subplots(4, 1, figsize=(10, 8), sharex=True)
    names = ["x (surge)", "y (sway)", "z (heave)", "yaw"]
    for i, ax in enumerate(axes):
        if s.commanded:
            ts = [t for t, _ in s.commanded] + [t_end]
            vs = [v[i] for _, v in s.commanded] + [s.commanded[-1][1][i]]
            ax.step(ts, vs, where="post", label="commanded (operator)", color="tab:blue")
        if s.received:
            ts = [t for t, _ in s.received]
            vs = [v[i] for _, v in s.received]
            ax.step(ts, vs, where="post", label="received (ROV)", color="tab:red", alpha=0.8)
        ax.set_ylabel(names[i])
        ax.set_ylim(-1.1, 1.1)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    axes[-1].set_xlabel("session time (s)")
    axes[-1].set_xlim(0, max(t_end, 1.0))
    fig.suptitle("Velocity commanded on the console vs received by the ROV (fraction of maximum)")
    fig.tight_layout()
    fig5 = out / "fig5_velocity.png"
    fig.savefig(fig5, dpi=110)
    plt.close(fig)
    return [fig4, fig5]


def _acoustic_fig5(s: Series, out: Path, t_end: float, plt) -> Path:
    """The acoustic link has no sticks: where the statuses put the vehicle, beside
    the go-tos sent (north, east, depth) and its heading."""
    fig, axes = plt.subplots(4, 1, figsize=(10, 8), sharex=True)
    names = ["north x (m)", "east y (m)", "depth z (m)", "heading (deg)"]
    for i, ax in enumerate(axes):
        pts = [(st[0], st[1 + i]) for st in s.statuses if st[0] <= t_end]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", ms=3, color="tab:red", label="status (ROV)")
        if i < 3 and s.targets:
            ts = [t for t, *_ in s.targets] + [t_end]
            vs = [g[1 + i] for g in s.targets] + [s.targets[-1][1 + i]]
            ax.step(ts, vs, where="post", color="tab:blue", label="go-to sent (operator)")
        ax.set_ylabel(names[i])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    axes[-1].set_xlabel("session time (s)")
    axes[-1].set_xlim(0, max(t_end, 1.0))
    fig.suptitle("Acoustic link: the go-tos sent and the position the statuses report")
    fig.tight_layout()
    fig5 = out / "fig5_position.png"
    fig.savefig(fig5, dpi=110)
    plt.close(fig)
    return fig5
