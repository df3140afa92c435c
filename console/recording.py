"""Recorded sessions: reading them, playing them back, plotting them.

A recording (written by `console.session.recorder.Recorder`) is JSON lines, each with
`k` (kind) and `t` (session seconds): "meta" first, then "tx"/"rx" frames as
hex, "wish" velocity changes, "order" and "order_state", "pose", "image".

Playback (`replaycontrol`: a timeline to pause, seek and change speed) needs no ROV: the received bytes are parsed again with the
link's own FrameDecoder and Reply, image trunks put together by the
master's own `link.assembly.ImageAssembly`, and the resulting events handed to an Operator,
which shows them as if live (its scene and web page work unchanged).

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

from rovlink.link.assembly import ImageAssembly
from rovlink.link.frame import MAX_FRAME, FrameDecoder
from rovlink.link.master import ImageComplete, ImageProgress, PoseReceived
from rovlink.link.messages import VELOCITY_FULL, Poll, ProtocolError, Reply


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
                if record.get("profile", "radio") != "radio":
                    raise RecordingError(
                        f"{path}: a recording of the {record.get('profile')} link (its packets, statuses and "
                        "log as JSON lines, docs/PROTOCOL.md §9); replay and its plots read radio sessions only")
                first = False
            yield record
    if first:
        raise RecordingError(f"{path}: empty recording")


NO_IMAGE = -1  # no image object begun (IMG is 0..7)


class ReplyReplayer:
    """Turns received bytes back into the master's events, without a master."""

    def __init__(self, *, skip_first_image: bool = True) -> None:
        self.decoder = FrameDecoder()
        self.image = ImageAssembly(NO_IMAGE)
        # As the master (protocol 1.1, §4): the first image completed after
        # start is not shown; it may be a capture of any age.
        self._images_to_skip = 1 if skip_first_image else 0

    def feed(self, data: bytes, t: float) -> list:
        """Received bytes as recorded (protocol 1.1: the link's own frames)."""
        events: list = []
        for payload in self.decoder.feed(data):
            events.extend(self.feed_payload(payload, t))
        return events

    def feed_payload(self, payload: bytes, t: float, *, sync: bool = False) -> list:
        """One reply payload the master was given (protocol 2 records these:
        authentic, timely, tag removed; a SYNC's reply part with `sync`)."""
        events: list = []
        try:
            reply = Reply.decode(payload, allow_sync=sync)
        except ProtocolError:
            return events
        events.append(PoseReceived(reply, t, None))
        if not reply.has_trunk:
            return events
        img = self.image
        if reply.img != img.img:
            if reply.offset != 0:
                return events
            self.image = img = ImageAssembly(reply.img, t)
        if not img.add(reply.offset, reply.trunk):
            return events
        skipping = self._images_to_skip > 0
        if not skipping:
            events.append(ImageProgress(img.img, len(img.data), img.total, img.stream))
        if img.complete:
            if skipping:
                self._images_to_skip -= 1
            else:
                events.append(ImageComplete(img.img, img.stream, img.started_at, t))
            self.image = ImageAssembly(NO_IMAGE)
        return events


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


def series(path: str | Path) -> Series:
    records = list(read_records(path))
    meta = records[0]
    bitrate = float(meta.get("bitrate_bps", 1900.0))
    delay = float(meta.get("delay_s", 0.085))
    frames, received, images = [], [], []
    commanded: list = [(0.0, (0.0, 0.0, 0.0, 0.0))]  # the wish is neutral until the pilot moves
    last_poll = None
    last_wish = None  # the last VELOCITY's wish (a version 2 NONE poll repeats it)
    replies = FrameDecoder()
    extra = 0  # bytes after a poll's payload: COUNT and TAG in protocol 2
    for r in records[1:]:
        k, t = r.get("k"), float(r.get("t", 0.0))
        if k == "link":
            extra = 5 if r.get("version") == 2 else 0
        elif k == "tx":
            data = bytes.fromhex(r["hex"])
            frames.append((t, "tx", len(data)))
            try:
                if extra and data[2] & 0x40:  # a HELLO
                    raise ProtocolError("HELLO")
                # The poll as the master made it (version 2 may leave parts out of the frame, §8.1).
                poll = Poll.decode(bytes.fromhex(r["poll"]) if "poll" in r else data[2:len(data) - 2 - extra])
                order = poll.order
                if hasattr(order, "vyaw"):
                    wish = (order.vx / VELOCITY_FULL, order.vy / VELOCITY_FULL, order.vz / VELOCITY_FULL,
                            order.vyaw / VELOCITY_FULL)
                elif extra and order.code == 0:
                    wish = last_wish  # version 2: a NONE poll repeats the last wish the ROV took (§8.1)
                else:
                    wish = last_wish = None
                last_wish = wish
                last_poll = (t + 8 * len(data) / bitrate + delay, wish) if wish is not None else None
            except ProtocolError:
                last_poll = None
        elif k == "rx":
            data = bytes.fromhex(r["hex"])
            frames.append((t, "rx", len(data)))
            if not extra and replies.feed(data) and last_poll is not None:
                received.append(last_poll)
                last_poll = None
        elif k == "reply" and extra and not r.get("sync"):
            # Version 2: an authentic, timely reply (its frame has no CRC to find it by, §8.1).
            if last_poll is not None:
                received.append(last_poll)
                last_poll = None
        elif k == "wish":
            commanded.append((t, tuple(v / VELOCITY_FULL for v in r["v"])))
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
