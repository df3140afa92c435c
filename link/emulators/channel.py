"""A narrow wireless channel between two endpoints, emulated (docs/PROTOCOL.md §7).

Goals: reproduce what a 1-2 kbit/s RF or acoustic modem does to the bytes,
after the link models of ns-3 and UWSim: serialisation at the bitrate, an
intrinsic (modem) delay, a propagation delay, bit errors that flip real bits
(so the CRC must catch them), random packet loss, a finite transmit queue that
drops when full, and half-duplex collisions.  Runs reproduce from a seed, and
every transmit, receive, drop and corruption is logged with its time: the
data behind a time-lapse like the paper's Fig. 4.

Plan: sans-I/O and clock-free like the protocol machines.  `send(side, data,
now)` queues a packet at the transmitter of side "a" or "b"; `next_time()`
says when the next packet arrives; `deliver(now)` returns the packets that
have arrived by then, to the other side.  The same object serves simulated
time (tests, benchmarks) and real time (`rovlink channel`, the demo) through
the drivers in `link.aio`.

Model, per packet sent by X at time t:
    start   = max(t, X's transmitter free)          (FIFO queue)
    air     = [start + delay, start + delay + 8 n / bitrate]
    arrival = air end + propagation
A packet is received over [air start + propagation, arrival]; with
half-duplex on it is lost if the receiver was itself on the air during that
interval (a modem cannot hear while it talks).
"""

from __future__ import annotations

import heapq
import json
import math
import random
from dataclasses import dataclass
from typing import IO, Callable

SIDES = ("a", "b")


def event_log(log: Callable[[dict], None] | IO[str] | None) -> Callable[[dict], None] | None:
    """What a channel model writes its events to: a callable taking each record, or a
    text file given one JSON line per record, or nothing."""
    if log is None:
        return None
    if callable(log):
        return log
    return lambda record: log.write(json.dumps(record, separators=(",", ":")) + "\n")


@dataclass(frozen=True)
class LinkParams:
    """One direction of the channel."""

    bitrate_bps: float = 1900.0
    delay_s: float = 0.085  # intrinsic (modem) delay
    propagation_s: float = 0.0  # distance / speed of the wave
    ber: float = 0.0  # bit error rate
    loss: float = 0.0  # probability a whole packet is lost (the long-run fraction, with bursts too)
    # Losses in bursts (a Gilbert-Elliott channel): the mean number of packets
    # lost in a row; 1 (the default) loses packets independently.
    burst: float = 1.0
    queue_bytes: int = 2048  # transmit queue; a packet that does not fit is dropped

    def __post_init__(self) -> None:
        if not self.bitrate_bps > 0:
            raise ValueError(f"bitrate must be positive, got {self.bitrate_bps}")
        if self.delay_s < 0 or self.propagation_s < 0:
            raise ValueError("delays must not be negative")
        if not 0.0 <= self.ber < 1.0:
            raise ValueError(f"bit error rate must be in [0, 1), got {self.ber}")
        if not 0.0 <= self.loss <= 1.0:
            raise ValueError(f"packet loss rate must be in [0, 1], got {self.loss}")
        if self.queue_bytes < 1:
            raise ValueError("queue must hold at least one byte")
        if not self.burst >= 1.0:
            raise ValueError(f"mean loss burst must be at least 1 packet, got {self.burst}")
        if self.burst > 1.0 and self.loss >= 1.0:
            raise ValueError("a loss of 1 has no bursts")

    def tx_time(self, nbytes: int) -> float:
        return 8.0 * nbytes / self.bitrate_bps


@dataclass(frozen=True)
class Delivery:
    to: str  # "a" or "b"
    data: bytes
    at: float


@dataclass
class ChannelCounters:
    sent: int = 0
    delivered: int = 0
    corrupted: int = 0
    bits_flipped: int = 0
    lost: int = 0
    dropped_queue: int = 0
    collisions: int = 0


@dataclass
class _InFlight:
    sender: str
    data: bytes
    air_start: float
    air_end: float
    arrival: float
    seq: int


class Channel:
    """Two-sided emulated channel.  Side "a" sends with `a_to_b` parameters."""

    def __init__(
        self,
        a_to_b: LinkParams | None = None,
        b_to_a: LinkParams | None = None,
        *,
        half_duplex: bool = True,
        seed: int | None = 0,
        log: Callable[[dict], None] | IO[str] | None = None,
    ) -> None:
        self.params = {"a": a_to_b or LinkParams(), "b": b_to_a or a_to_b or LinkParams()}
        self.half_duplex = half_duplex
        self.rng = random.Random(seed)
        self.counters = ChannelCounters()
        self._log = event_log(log)
        self._tx_free = {"a": -math.inf, "b": -math.inf}
        self._queued: dict[str, list[tuple[float, int]]] = {"a": [], "b": []}  # (transmit end, bytes)
        self._air: dict[str, list[tuple[float, float]]] = {"a": [], "b": []}  # on-air intervals
        self._arrivals: list[tuple[float, int, _InFlight]] = []
        self._seq = 0
        self._in_burst = {"a": False, "b": False}  # Gilbert-Elliott state per sending side

    def _emit(self, record: dict) -> None:
        if self._log is not None:
            self._log(record)

    # ------------------------------------------------------------------

    def send(self, side: str, data: bytes, now: float) -> bool:
        """Queue `data` at side's transmitter; False if the queue dropped it."""
        if side not in SIDES:
            raise ValueError(f"side must be 'a' or 'b', got {side!r}")
        if not data:
            return True
        p = self.params[side]
        direction = f"{side}>{'b' if side == 'a' else 'a'}"
        queue = self._queued[side]
        queue[:] = [(end, n) for end, n in queue if end > now]
        waiting = sum(n for _, n in queue)
        if waiting + len(data) > p.queue_bytes:
            self.counters.dropped_queue += 1
            self._emit({"t": now, "ev": "drop", "dir": direction, "bytes": len(data), "why": "queue full"})
            return False
        self.counters.sent += 1
        start = max(now, self._tx_free[side])
        duration = p.tx_time(len(data))
        self._tx_free[side] = start + duration
        air_start = start + p.delay_s
        air_end = air_start + duration
        queue.append((start + duration, len(data)))
        self._air[side].append((air_start, air_end))
        self._seq += 1
        flight = _InFlight(side, bytes(data), air_start, air_end, air_end + p.propagation_s, self._seq)
        heapq.heappush(self._arrivals, (flight.arrival, flight.seq, flight))
        self._emit(
            {"t": now, "ev": "tx", "dir": direction, "bytes": len(data), "start": start, "air_end": air_end,
             "arrival": flight.arrival}
        )
        return True

    def next_time(self) -> float | None:
        """When the next packet arrives somewhere; None when nothing is in flight."""
        return self._arrivals[0][0] if self._arrivals else None

    def deliver(self, now: float) -> list[Delivery]:
        """Packets that have arrived by `now`, after loss, collisions and bit errors."""
        out: list[Delivery] = []
        while self._arrivals and self._arrivals[0][0] <= now:
            _, _, f = heapq.heappop(self._arrivals)
            receiver = "b" if f.sender == "a" else "a"
            direction = f"{f.sender}>{receiver}"
            p = self.params[f.sender]
            rx_start = f.air_start + p.propagation_s
            if self.half_duplex and self._on_air(receiver, rx_start, f.arrival):
                self.counters.collisions += 1
                self._emit({"t": f.arrival, "ev": "collision", "dir": direction, "bytes": len(f.data)})
                continue
            if p.loss and self._lose(f.sender, p):
                self.counters.lost += 1
                self._emit({"t": f.arrival, "ev": "loss", "dir": direction, "bytes": len(f.data)})
                continue
            data, flipped = self._flip_bits(f.data, p.ber)
            if flipped:
                self.counters.corrupted += 1
                self.counters.bits_flipped += flipped
                self._emit({"t": f.arrival, "ev": "corrupt", "dir": direction, "bytes": len(data), "bits": flipped})
            self.counters.delivered += 1
            # late_s: how long after its arrival the packet was handed on (this process's
            # own lateness, on a loaded machine), told apart from the ends' own.
            self._emit({"t": f.arrival, "ev": "rx", "dir": direction, "bytes": len(data),
                        "late_s": round(max(0.0, now - f.arrival), 6)})
            out.append(Delivery(receiver, data, f.arrival))
        self._prune(now)
        return out

    # ------------------------------------------------------------------

    def _lose(self, sender: str, p: LinkParams) -> bool:
        """Whether the next packet from `sender` is lost.  With bursts, a two-state
        chain per packet: a burst ends with probability 1/burst (so bursts last
        `burst` packets on average) and starts with the probability that makes the
        long-run loss `loss`: q = loss / burst / (1 - loss)."""
        if p.burst <= 1.0:
            return self.rng.random() < p.loss
        if self._in_burst[sender]:
            self._in_burst[sender] = self.rng.random() >= 1.0 / p.burst
        else:
            self._in_burst[sender] = self.rng.random() < p.loss / p.burst / (1.0 - p.loss)
        return self._in_burst[sender]

    def _on_air(self, side: str, t0: float, t1: float) -> bool:
        return any(s < t1 and e > t0 for s, e in self._air[side])

    def _prune(self, now: float) -> None:
        # Air intervals matter only while a packet that overlaps them is in
        # flight; keep a generous horizon.
        horizon = now - 60.0
        for side in SIDES:
            air = self._air[side]
            if air and air[0][1] < horizon:
                self._air[side] = [(s, e) for s, e in air if e >= horizon]

    def _flip_bits(self, data: bytes, ber: float) -> tuple[bytes, int]:
        if ber <= 0.0:
            return data, 0
        nbits = 8 * len(data)
        log_keep = math.log1p(-ber)
        pos = -1
        flipped = 0
        buf = None
        while True:
            # Geometric gap to the next error: one draw per error, not per bit.
            u = self.rng.random()
            pos += 1 + int(math.log(1.0 - u) / log_keep)
            if pos >= nbits:
                break
            if buf is None:
                buf = bytearray(data)
            buf[pos >> 3] ^= 0x80 >> (pos & 7)
            flipped += 1
        return (bytes(buf) if buf is not None else data), flipped
