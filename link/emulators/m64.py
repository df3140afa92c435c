"""The channel emulator's Water Linked Modem-M64: 8-byte packets taking turns.

Goals: what a pair of Modem-M64 acoustic modems does to the packets handed
to them, seen from their serial ports, so that the acoustic profile can be
built and benchmarked in simulated time (`link.sim.SimLink`) and in real time
(`link.aio.run_channel`) exactly as the radio one is with `link.channel`:
the same interface (`send(side, data, now) -> bool`, `next_time()`,
`deliver(now) -> list[Delivery]`, `counters`, a JSON-lines log, a seed),
sans-I/O and clock-free.

What the modem is (the facts this model rests on, and where they come from):

- 64 bit/s net, both ways; two-way, half duplex; 200 m range.  Water Linked,
  "Modem-M64" documentation page (github.com/waterlinked/docs,
  docs/modems/modem-m64.md, "Key specifications"; the same on
  waterlinked.github.io docs/modem/modem-m64.md and waterlinked.com).
- A packet is 8 bytes of payload (64 bits): the protocol's payload size
  command answers `wrn,8` ("For Water Linked Modem-M64 the payload size is 8
  bytes", Modem-M64 serial protocol, waterlinked.github.io
  docs/modem/modem-m64-protocol.md; wlmodem 1.3.0's simulator answers 8 too).
- One packet a second each way: "The LED will blink each time it receives a
  packet from the other modem (once a second)" (docs/modem/modem-m64.md), which
  with 8-byte packets is the documented 64 bit/s each way.  wlmodem's
  simulator hands out one queued packet per second (`next_duration=1.0`).
- Latency 1.5-2.5 s ("Key specifications", docs/modems/modem-m64.md).  (The
  marketing page waterlinked.com/underwater-communication says "typical
  latency ~500ms"; the product documentation is the later and the one this
  model follows.)
- Turns: the two modems of a pair are configured on the same channel (1-7)
  with different roles.  "The modem with role A will always transmit.  The
  modem with role B will listen until it detects a signal from a modem of
  role A.  It will then start transmitting responses back"; after sync "each
  modem [is] given dedicated timeslots where they are allowed to transmit and
  when they shall listen" (protocol page; waterlinked.com).  The host has no
  say in when a queued packet leaves (wlmodem's example/latency.py: "We don't
  know exactly when the modem transmits").
- When nothing is queued the modem sends an all-zero sync packet, which the
  receiver filters out: an all-zero payload is reserved and never delivered
  (protocol page, note and [2]).
- Establishing the link takes "a few seconds" (waterlinked.com, "Auto Sync");
  wlmodem's simulator reports the link down for 3 s after a configuration
  (`link_up_duration=3.0`).  Out of reach the modems enter search mode and
  "will not transmit payload packages" until they re-sync; role B goes back
  to listening after "several consecutive packets" from A cannot be decoded
  (protocol page; the number is not given).
- Loss: a packet that cannot be decoded is counted in the diagnostic's
  `packet_loss_count` and is gone: the modem does not retransmit (wlmodem's
  WlUDPSocket notes that any single lost packet spoils a datagram "while still
  taking the full time to transmit").
- Transmit queue: `wcl` answers the number of packets waiting and `wcq`
  answers ACK or NAK.  The depth is NOT documented; the protocol page's own
  example answer is `wrl,107`, so a queue of at least that many is what Water
  Linked showed.  The model's default, 128 packets, is an assumption (a
  parameter); a packet that does not fit is refused, as a NAK would be.

Model (M64Params; every figure a parameter):

- Time starts at `start` (or the first `now` the model is given); the link is
  up `sync_s` (3 s) later.  From then on role "a" owns the turns at
  up + k * round_s and role "b" those at up + b_offset_s + k * round_s
  (round_s = 1 s, b_offset_s = 0.5 s): one packet per side per second, never
  both at once.
- At its turn a side sends the oldest packet of its FIFO queue (of
  `queue_packets`, 128); it reaches the other side's host `latency_s` (1.5 s)
  after its turn began.  A packet queued just after its side's turn waits up
  to one round more, so latencies fall in 1.5-2.5 s: the documented range.
  The time on the water and the travel (200 m at 1500 m/s: 0.13 s) are inside
  that latency.
- Loss per direction (M64Loss): with `burst` 1 (the default) every packet is
  lost independently with probability `loss`; with `burst` above 1, a Gilbert-Elliott
  chain (a good state that loses nothing, a bad state that loses every
  packet) makes losses come in bursts of `burst` packets on average while
  the long-run fraction lost stays `loss`: P(bad -> good) = 1 / burst,
  P(good -> bad) = loss / (burst * (1 - loss)).  The chain steps once per data
  packet sent in that direction.
- `drop_link(now)` emulates the modems losing each other (out of range):
  whatever is on its way is lost, queued packets wait, and the turns resume
  `sync_s` later.  Loss alone never drops the link in this model (the real
  modem's "several consecutive packets" is not quantified).
- Only packets of exactly 8 bytes that are not all zero are accepted; anything
  else raises ValueError (a caller bug: the modem would refuse the size, or
  send the zeros as its own sync packet and the receiver would drop them).
"""

from __future__ import annotations

import heapq
import math
import random
from collections import deque
from dataclasses import dataclass
from typing import IO, Callable

from .channel import ChannelCounters, Delivery, event_log

SIDES = ("a", "b")
PACKET_BYTES = 8


@dataclass(frozen=True)
class M64Params:
    """Timing and queue of a Modem-M64 pair (both directions)."""

    round_s: float = 1.0  # one packet per side per round: 8 bytes/s = 64 bit/s each way
    b_offset_s: float = 0.5  # role b's turn, this long after role a's
    latency_s: float = 1.5  # from the start of a turn to the packet at the other host
    queue_packets: int = 128  # transmit queue (undocumented depth: an assumption)
    sync_s: float = 3.0  # from power-up / loss of the link to the first turn

    def __post_init__(self) -> None:
        if not self.round_s > 0:
            raise ValueError(f"round_s must be positive, got {self.round_s}")
        if not 0 < self.b_offset_s < self.round_s:
            raise ValueError(f"b_offset_s must lie inside the round (0, {self.round_s}), got {self.b_offset_s}")
        if self.latency_s < 0 or self.sync_s < 0:
            raise ValueError("latency_s and sync_s must not be negative")
        if self.queue_packets < 1:
            raise ValueError(f"the transmit queue must hold at least one packet, got {self.queue_packets}")


@dataclass(frozen=True)
class M64Loss:
    """Packet loss in one direction: `loss` per packet, in bursts of `burst` packets on average."""

    loss: float = 0.0
    burst: float = 1.0  # mean burst length in packets (Gilbert-Elliott); 1: independent losses

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss <= 1.0:
            raise ValueError(f"packet loss must be in [0, 1], got {self.loss}")
        if not self.burst >= 1.0:
            raise ValueError(f"a mean burst is at least 1 packet long, got {self.burst}")
        if self.bursty:
            if self.loss >= 1.0:
                raise ValueError("bursts need some packets to get through: loss must be below 1")
            if self.good_to_bad > 1.0:
                raise ValueError(f"bursts of {self.burst} packets on average cannot lose {self.loss:.0%} of the packets: "
                                 f"the burst must be at least {self.loss / (1 - self.loss):.2f} packets")

    @property
    def bursty(self) -> bool:
        return self.burst > 1.0

    @property
    def bad_to_good(self) -> float:
        return 1.0 / self.burst

    @property
    def good_to_bad(self) -> float:
        if not self.bursty:
            return 0.0
        return self.loss * self.bad_to_good / (1.0 - self.loss)


@dataclass
class M64Counters(ChannelCounters):
    """ChannelCounters (corrupted, bits_flipped and collisions stay 0: the modem
    delivers whole packets or none, and its turns never collide) plus bursts."""

    bursts: int = 0  # times a direction's chain entered its bad state
    links_dropped: int = 0


@dataclass
class _InFlight:
    sender: str
    data: bytes
    queued: float
    turn: float
    arrival: float
    lost: bool
    seq: int


class M64Channel:
    """Two Modem-M64s, role "a" at side "a" and role "b" at side "b"."""

    def __init__(
        self,
        params: M64Params | None = None,
        a_to_b: M64Loss | None = None,
        b_to_a: M64Loss | None = None,
        *,
        seed: int | None = 0,
        log: Callable[[dict], None] | IO[str] | None = None,
        start: float | None = None,
    ) -> None:
        self.params = params or M64Params()
        self.loss = {"a": a_to_b or M64Loss(), "b": b_to_a or a_to_b or M64Loss()}
        root = random.Random(seed)
        # One stream per direction: what a loses does not depend on when b talks.
        self.rng = {side: random.Random(root.getrandbits(64)) for side in SIDES}
        self.counters = M64Counters()
        self._log = event_log(log)
        self._queue: dict[str, deque[tuple[bytes, float]]] = {"a": deque(), "b": deque()}
        self._bad = {"a": False, "b": False}  # Gilbert-Elliott state per direction
        self._arrivals: list[tuple[float, int, _InFlight]] = []
        self._seq = 0
        self._up_at: float | None = None  # the link's first turn (role a's)
        self._turn = {"a": 0, "b": 0}  # index of each side's next turn not yet taken
        if start is not None:
            self._begin(start)

    def _emit(self, record: dict) -> None:
        if self._log is not None:
            self._log(record)

    # -- time ----------------------------------------------------------------

    def _begin(self, now: float) -> None:
        self._up_at = now + self.params.sync_s
        self._turn = {"a": 0, "b": 0}
        self._emit({"t": now, "ev": "link", "state": "syncing", "up_at": self._up_at})

    def _turn_time(self, side: str, k: int) -> float:
        assert self._up_at is not None
        offset = 0.0 if side == "a" else self.params.b_offset_s
        return self._up_at + offset + k * self.params.round_s

    def _first_turn_after(self, side: str, now: float) -> int:
        offset = 0.0 if side == "a" else self.params.b_offset_s
        k = math.floor((now - self._up_at - offset) / self.params.round_s) + 1
        k = max(k, 0)
        while k > 0 and self._turn_time(side, k - 1) > now:  # floating-point edges
            k -= 1
        return k

    def _advance(self, now: float) -> None:
        """Take every turn up to `now`, in time order."""
        if self._up_at is None:
            self._begin(now)
        while True:
            due = [(self._turn_time(s, self._turn[s]), s) for s in SIDES]
            t, side = min(due)
            if t > now:
                return
            if not self._queue["a"] and not self._queue["b"]:
                # Nothing to send: the turns pass with sync packets only.
                for s in SIDES:
                    self._turn[s] = max(self._turn[s], self._first_turn_after(s, now))
                return
            self._turn[side] += 1
            if self._queue[side]:
                self._transmit(side, t)

    def _transmit(self, side: str, turn: float) -> None:
        data, queued = self._queue[side].popleft()
        self.counters.sent += 1
        lost = self._draw_loss(side)
        self._seq += 1
        flight = _InFlight(side, data, queued, turn, turn + self.params.latency_s, lost, self._seq)
        heapq.heappush(self._arrivals, (flight.arrival, flight.seq, flight))
        self._emit({"t": turn, "ev": "tx", "dir": _direction(side), "bytes": len(data), "queued": queued,
                    "arrival": flight.arrival, "waiting": len(self._queue[side])})

    def _draw_loss(self, side: str) -> bool:
        p = self.loss[side]
        rng = self.rng[side]
        if not p.bursty:
            return bool(p.loss) and rng.random() < p.loss
        if self._bad[side]:
            if rng.random() < p.bad_to_good:
                self._bad[side] = False
        elif rng.random() < p.good_to_bad:
            self._bad[side] = True
            self.counters.bursts += 1
        return self._bad[side]

    # -- the Channel interface -------------------------------------------------

    def send(self, side: str, data: bytes, now: float) -> bool:
        """Queue one 8-byte packet at side's modem; False if its queue is full."""
        if side not in SIDES:
            raise ValueError(f"side must be 'a' or 'b', got {side!r}")
        if len(data) != PACKET_BYTES:
            raise ValueError(f"the Modem-M64 carries packets of exactly {PACKET_BYTES} bytes, got {len(data)}")
        if not any(data):
            raise ValueError("an all-zero packet is the Modem-M64's own sync packet: the receiver would drop it")
        self._advance(now)
        queue = self._queue[side]
        if len(queue) >= self.params.queue_packets:
            self.counters.dropped_queue += 1
            self._emit({"t": now, "ev": "drop", "dir": _direction(side), "bytes": len(data), "why": "queue full"})
            return False
        queue.append((bytes(data), now))
        self._emit({"t": now, "ev": "queue", "dir": _direction(side), "bytes": len(data), "waiting": len(queue)})
        return True

    def next_time(self) -> float | None:
        """When something next happens: a packet arrives, or a side with a packet
        waiting has its turn.  None when nothing is queued or on its way."""
        times = [self._arrivals[0][0]] if self._arrivals else []
        if self._up_at is not None:
            times += [self._turn_time(s, self._turn[s]) for s in SIDES if self._queue[s]]
        return min(times) if times else None

    def deliver(self, now: float) -> list[Delivery]:
        """Packets that have reached the other side's host by `now`."""
        self._advance(now)
        out: list[Delivery] = []
        while self._arrivals and self._arrivals[0][0] <= now:
            _, _, f = heapq.heappop(self._arrivals)
            receiver = "b" if f.sender == "a" else "a"
            if f.lost:
                self.counters.lost += 1
                self._emit({"t": f.arrival, "ev": "loss", "dir": _direction(f.sender), "bytes": len(f.data)})
                continue
            self.counters.delivered += 1
            self._emit({"t": f.arrival, "ev": "rx", "dir": _direction(f.sender), "bytes": len(f.data),
                        "latency": f.arrival - f.queued})
            out.append(Delivery(receiver, f.data, f.arrival))
        return out

    # -- beyond Channel ------------------------------------------------------

    def is_up(self, now: float) -> bool:
        """Whether the modems are in sync at `now` (what the diagnostic's link flag says)."""
        if self._up_at is None:
            self._begin(now)
        return now >= self._up_at

    def queue_length(self, side: str) -> int:
        """Packets waiting at side's modem (what `wcl` answers), as of the last call."""
        return len(self._queue[side])

    def flush(self, side: str, now: float) -> int:
        """Empty side's transmit queue (the modem's `wcf`); returns how many were dropped."""
        self._advance(now)
        n = len(self._queue[side])
        self._queue[side].clear()
        if n:
            self._emit({"t": now, "ev": "flush", "dir": _direction(side), "packets": n})
        return n

    def drop_link(self, now: float, resync_s: float | None = None) -> None:
        """The modems lose each other at `now`: what is on its way is lost,
        queued packets wait, the turns resume `resync_s` (default sync_s) later."""
        self._advance(now)
        for _, _, f in self._arrivals:
            f.lost = True
        self.counters.links_dropped += 1
        self._up_at = now + (self.params.sync_s if resync_s is None else resync_s)
        self._turn = {"a": 0, "b": 0}
        self._emit({"t": now, "ev": "link", "state": "down", "up_at": self._up_at})


def _direction(side: str) -> str:
    return f"{side}>{'b' if side == 'a' else 'a'}"
