"""The operator's end of the link (docs/PROTOCOL.md §2–5), without I/O.

Goals: the pilot's freshest wish reaches the ROV every cycle; every one-shot
order runs exactly once whatever is lost; the image arrives as fast as the
channel allows and is shown refining as it comes.

Plan: the master owns the token.  `next_poll(now)` returns the next poll frame
when the token is ours (the last reply came, or its timeout passed), else
None.  `receive(payload, now)` consumes a reply payload (or `receive_bytes`
raw bytes through the master's own FrameDecoder) and returns events.
`deadline()` says when to call `next_poll` again if nothing arrives.

Events for the console: `PoseReceived` (the whole reply: its HOLD,
ATTITUDE_VALID, REJECTED and REASON bits too), `OrderAcknowledged` (taken and
carried out), `OrderRejected` (ACK flipped with REJECTED: its REASON),
`OrderCancelled` (a pending order a STOP cancelled that the ROV never took, or
a STOP the pilot cancelled), `OrderNotSent` (queued orders a STOP cancelled),
`StopConfirmed` / `StopNotCarriedOut`, `RequestExpired`, the image events
(`ImageAbandoned` also when the ROV restarts an image: FIRST over a partial
copy) and `ReplyLost`.

Rules of docs/PROTOCOL.md 1.1 kept here: one one-shot order pending at a time,
sent with SEQ = not ACK until a reply's ACK equals it, the wish in every other
poll meanwhile; every other poll carries SEQ = ACK; no one-shot order until 3 s
after the first reply (STOP as soon as there is one); STOP in every poll until
a reply to a STOP poll shows HOLD, AUTOPILOT and POS_HOLD or DEPTH_HOLD; an
ARM or MODE request until a reply shows it done or for 3 s, and a request
equal to the last one the ROV saw goes out only after a reply to a poll with
that field 0; after the start, a STOP or a restarted ROV's SYNC, requests
(but a disarm) go out as 0 until a reply to a VELOCITY poll comes (the first
VELOCITY the ROV takes then only sets its reference); the receive LEN cap
follows the last poll's SIZE.

Decisions where docs/PROTOCOL.md is silent:
- A STOP pressed while one is being sent joins it: both ids are confirmed,
  shown not carried out or cancelled together.
- A STOP whose replies show AUTOPILOT 0 is reported (`StopNotCarriedOut`)
  once per spell; `cancel_stop()` is allowed only then.  The STOP goes on
  being sent until it is confirmed or cancelled.
- A pending order a STOP cancelled is watched: an ACK flip to its SEQ
  reports it (taken or rejected); when the STOP is confirmed or cancelled
  without such a flip it is reported `OrderCancelled` ("not taken").
- SIZE class: while steering (a non-neutral wish, or one changed within
  `steer_hold_s`) or sending a STOP, the small `steering_size`, for a short
  command cycle.  While a pilot holds control (`attended`) and has moved the
  sticks within `react_window_s`, the same: the first wish after a pause
  reaches the ROV within a steering cycle.  Attended but still for longer,
  at most `attended_size` (SIZE 2, 96 bytes): the pose shown stays under
  1.5 s old.
  Otherwise the class with the best expected goodput for the bit error rate
  the master has observed (lost replies per bit sent); at a clean link that
  is SIZE 3, at BER 1e-3 it is SIZE 1.
- The first IMG is chosen at random, and the first image completed after
  start is not shown (`skip_first_image`, §4 (1.1)): it may be a capture of
  any age the ROV still held.  IMAGE settings sent: the next IMG is asked for
  in the same poll (the ROV executes the order before it serves the request).
- Known limit of the one-bit SEQ (§3): if the ROV restarts while a reply
  from before the restart is still in flight, the next order can go out with
  SEQ equal to the fresh ACK 0 and be taken for a repeat.  Nothing on the
  wire tells that window apart in version 1.1 (version 2's BOOT does).
- With `retransmit=False` (the paper's baseline) a lost reply abandons the
  image being received and the next IMG is asked for.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import random
from dataclasses import dataclass
from typing import Deque

from ..report import VehicleReport, report_from_reply
from .assembly import ImageAssembly
from .events import (
    PILOT_SKIPPED,
    ImageAbandoned,
    ImageComplete,
    ImageProgress,
    OrderAcknowledged,
    OrderCancelled,
    OrderFateUnknown,
    OrderNotSent,
    OrderRejected,
    PollSent,
    PoseReceived,
    ReplyLost,
    RequestExpired,
    StopConfirmed,
    StopNotCarriedOut,
)
from .frame import MAX_FRAME, OVERHEAD, FrameDecoder, encode_frame
from .messages import (
    IMG_IDS,
    NO_IMAGE_DATA,
    REPLY_HEADER,
    REPLY_IMAGE_HEADER,
    REQUESTABLE_MODES,
    SIZE_CLASS_BYTES,
    Arm,
    ImageSettings,
    Mode,
    NoOrder,
    Poll,
    Position,
    ProtocolError,
    Reply,
    ReservedOrder,
    Stop,
    Velocity,
    next_img,
)

# §5's shortest margin: the timeout's after a lost reply, in version 2 (§8.1).
OUTAGE_MARGIN_S = 0.05


class FrameSizes:
    """Version 1.1's frame lengths, for timeouts and the SIZE choice (version 2
    hands the master its own: `link.secure`)."""

    def __init__(self, max_frame: int) -> None:
        self.max_frame = max_frame

    def poll(self, poll: Poll) -> int:
        """The frame of `poll` (at most)."""
        return OVERHEAD + len(poll.encode())

    def reply(self, size: int) -> int:
        """The longest reply frame a poll of SIZE `size` allows."""
        return OVERHEAD + REPLY_IMAGE_HEADER + min(SIZE_CLASS_BYTES[size], self.max_frame - OVERHEAD - REPLY_IMAGE_HEADER)

    def reply_without_image(self) -> int:
        return OVERHEAD + REPLY_HEADER

    def trunk(self, size: int) -> int:
        """The trunk such a reply carries (at least)."""
        return self.reply(size) - OVERHEAD - REPLY_IMAGE_HEADER

    def velocity_poll(self) -> int:
        """The poll the SIZE choice reckons with: the wish, every other cycle at least."""
        return self.poll(Poll(order=Velocity()))


@dataclass
class MasterStats:
    polls_sent: int = 0
    replies: int = 0
    replies_lost: int = 0
    protocol_errors: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0
    images_started: int = 0
    images_completed: int = 0
    images_abandoned: int = 0
    last_round_trip_s: float | None = None


@dataclass
class _PendingOrder:
    order_id: int
    order: object
    sent: bool = False
    seq: int = 0  # the SEQ it carries, fixed when first sent


@dataclass
class _StopState:
    order_ids: list[int]  # a STOP pressed again while one is sent joins it
    not_carried_out: bool = False  # StopNotCarriedOut reported for this spell
    orphan: _PendingOrder | None = None  # the pending order it cancelled, fate unknown yet


class Master:
    """Operator-side protocol state machine (sans I/O)."""

    def __init__(
        self,
        *,
        bitrate_bps: float = 1900.0,
        delay_s: float = 0.085,
        margin_s: float = 0.15,
        steering_size: int = 0,
        idle_size: int | None = None,
        steer_hold_s: float = 1.5,
        react_window_s: float = 10.0,
        attended_size: int = 2,
        max_frame: int = MAX_FRAME,
        retransmit: bool = True,
        images: bool = True,
        request_hold_s: float = 3.0,
        start_wait_s: float = 3.0,
        skip_first_image: bool = True,
        first_img: int | None = None,
        rng: random.Random | None = None,
    ) -> None:
        if bitrate_bps <= 0:
            raise ValueError("bitrate_bps must be positive")
        if not 0 <= steering_size <= 3 or (idle_size is not None and not 0 <= idle_size <= 3):
            raise ValueError("SIZE classes are 0..3")
        if max_frame < OVERHEAD + REPLY_HEADER:
            raise ValueError(f"max_frame must be at least {OVERHEAD + REPLY_HEADER} bytes")
        self.bitrate_bps = float(bitrate_bps)
        self.delay_s = float(delay_s)
        self.margin_s = float(margin_s)
        self.steering_size = steering_size
        self.idle_size = idle_size  # None: adapt to the observed error rate
        self.steer_hold_s = steer_hold_s
        self.react_window_s = react_window_s
        self.attended_size = attended_size
        # A pilot holds control (the console says so): cycles are sized for the
        # pilot's reaction, not only for picture throughput (see _choose_size).
        self.attended = False
        self.max_frame = min(max_frame, MAX_FRAME)
        self.retransmit = retransmit
        self.images_enabled = images
        self.request_hold_s = request_hold_s
        self.start_wait_s = start_wait_s
        self.stats = MasterStats()
        self.decoder = FrameDecoder(max_len=self.max_frame - OVERHEAD)
        self.sizes = FrameSizes(self.max_frame)  # the frame lengths of the link's version

        self._rng = rng or random.Random()
        self._wish = Velocity()
        self._wish_changed_at = -math.inf
        # Whether a pilot's own input is in force (see `set_pilot_in_force`).
        self.pilot_in_force = True
        # The pilot re-centred while the ROV showed HOLD: VELOCITY polls carry
        # zero axes until a reply shows HOLD gone or answers such a poll.
        self._recentre_owed = False
        # ARM and MODE requests: [value, since, needs a 0 first] (§2: acted on when they change)
        self._requests: dict[str, list | None] = {"arm": None, "mode": None}
        self._last_seen: dict[str, int] = {"arm": Arm.NONE, "mode": Mode.KEEP}  # in the last answered VELOCITY
        # §2 (1.1): the first VELOCITY the ROV takes after its start or a STOP
        # only sets its ARM/MODE reference, so a request riding in it would be
        # swallowed.  Until a reply to a VELOCITY poll sent after the last STOP
        # poll (or since the start) comes, requests go out as 0 (a disarm
        # excepted: it acts whenever it arrives), and they wait, not expire.
        self._reference_unset = True
        self._orders: Deque[_PendingOrder] = collections.deque()
        self._stop: _StopState | None = None
        self._next_order_id = 1
        self._ack: int | None = None  # ACK of the last reply; None before the first
        self._first_reply_at: float | None = None
        self._wish_turn = False  # while an order is pending, every other poll carries the wish
        # Version 2 (§8.1), set by link.secure: a NONE poll chained to the reply to a
        # VELOCITY poll (or to such a NONE poll) repeats that wish, so an unchanged
        # wish goes as NONE; and after a lost reply the next poll asks for no image
        # data and waits with the shortest margin, so that its answer, or its loss,
        # comes sooner (the failsafe's sake).
        self.repeat_by_none = False
        self.quick_after_loss = False
        self._velocity_taken: Velocity | None = None  # the wish the last reply's poll carried or repeated
        self._lost_last = False  # the last poll's reply was lost
        self._awaiting: tuple[float, Poll, int] | None = None  # (sent at, poll, reply bytes expected)
        self._events: list[object] = []
        first = self._rng.randrange(IMG_IDS) if first_img is None else first_img
        self._image = ImageAssembly(first)
        self._images_to_skip = 1 if skip_first_image else 0
        self._last_reply: Reply | None = None
        # Error-rate estimate for the SIZE choice: exponentially weighted
        # counts of cycles lost and bits at risk per cycle.
        self._ewma_lost = 0.0
        self._ewma_bits = 0.0
        self._ewma_n = 0.0

    # ------------------------------------------------------------------
    # What the pilot wants
    # ------------------------------------------------------------------

    @property
    def velocity(self) -> Velocity:
        return self._wish

    def set_velocity(self, vx: int, vy: int, vz: int, vyaw: int, now: float) -> None:
        """Soft-state wish, -127..127 per axis; raises ProtocolError if out of range."""
        wish = Velocity(vx, vy, vz, vyaw)
        if (wish.vx, wish.vy, wish.vz, wish.vyaw) != (self._wish.vx, self._wish.vy, self._wish.vz, self._wish.vyaw):
            self._wish_changed_at = now
        self._wish = wish

    def set_pilot_in_force(self, in_force: bool) -> None:
        """Whether the wish is a pilot's own input (a holder who has re-centred
        since taking control).  When it is not, a neutral wish is nobody's, and
        while the last reply shows HOLD it goes out as ORDER NONE, not as a
        VELOCITY of four zero axes: the ROV's HOLD is released only by a
        pilot's own re-centring (docs/PROTOCOL.md §5, (decided))."""
        self.pilot_in_force = bool(in_force)

    def set_attended(self, attended: bool) -> None:
        """Whether a pilot holds control: the SIZE choice then keeps the pilot's
        reaction short (`_choose_size`); with nobody in control, pictures first."""
        self.attended = bool(attended)

    def recentred(self) -> None:
        """The pilot's own input is neutral now (its sticks centred).  While the
        ROV shows HOLD, VELOCITY polls carry four zero axes until a reply to one
        comes, so that the re-centring reaches the ROV even if the sticks move
        again before the next poll; a neutral the console sets itself (STOP,
        nobody holding) never does this.  Owed only for a HOLD that began before
        it: a STOP sent or a failsafe reported after it forgets it (the stick held
        since then would otherwise drive as the HOLD goes)."""
        self._recentre_owed = True

    def request_arm(self, arm: bool, now: float) -> None:
        self._request("arm", Arm.ARM if arm else Arm.DISARM, now)

    def request_mode(self, mode: Mode | int, now: float) -> None:
        mode = Mode(mode)
        if mode not in REQUESTABLE_MODES:
            raise ProtocolError(f"mode {mode!r} cannot be requested")
        self._request("mode", mode, now)

    def _request(self, what: str, value: int, now: float) -> None:
        # A request equal to what the ROV saw last is no change: it goes out
        # only after a reply to a poll with that field 0 (§5).  A disarm acts always.
        needs_gap = value == self._last_seen[what]
        if what == "arm" and value == Arm.DISARM:
            needs_gap = False
        self._requests[what] = [value, now, needs_gap]

    def send_order(self, order: Position | ImageSettings | Stop | ReservedOrder) -> int:
        """Queue a one-shot order (or STOP); returns its id for the order events."""
        if not isinstance(order, (Position, ImageSettings, Stop, ReservedOrder)):
            raise ProtocolError(f"not a one-shot order: {order!r}")
        order_id = self._next_order_id
        self._next_order_id += 1
        if isinstance(order, Stop):
            self._start_stop(order_id)
        else:
            self._orders.append(_PendingOrder(order_id, order))
        return order_id

    def _start_stop(self, order_id: int) -> None:
        if self._stop is not None:
            self._stop.order_ids.append(order_id)  # the same STOP, confirmed together
            return
        # A re-centring before the STOP is not one for the HOLD it brings (§5, decided).
        self._recentre_owed = False
        orphan = None
        for p in self._orders:
            if p.sent:
                orphan = p  # its fate is what the next replies show
            else:
                self._events.append(OrderNotSent(p.order_id, p.order, "cancelled by STOP"))
        self._orders.clear()
        self._stop = _StopState([order_id], orphan=orphan)

    def cancel_stop(self) -> bool:
        """Give up a STOP shown as not carried out (no autopilot), so that other
        orders (a DISARM, a SURFACE) can go out.  False if there is none to cancel."""
        stop = self._stop
        if stop is None or not stop.not_carried_out:
            return False
        self._stop = None
        for order_id in stop.order_ids:
            self._events.append(OrderCancelled(order_id, Stop(), "cancelled by the pilot"))
        self._settle_orphan(stop)
        return True

    def _settle_orphan(self, stop: _StopState) -> None:
        if stop.orphan is not None:
            p, stop.orphan = stop.orphan, None
            self._events.append(OrderCancelled(p.order_id, p.order, "not taken: cancelled by STOP"))

    @property
    def stopping(self) -> bool:
        """A STOP is being sent (not yet confirmed)."""
        return self._stop is not None

    # ------------------------------------------------------------------
    # Timing
    # ------------------------------------------------------------------

    def tx_time(self, nbytes: int) -> float:
        return 8.0 * nbytes / self.bitrate_bps

    def reply_frame_bytes(self, size: int) -> int:
        return self.sizes.reply(size)

    def trunk_bytes(self, size: int) -> int:
        """The trunk a reply to a poll of SIZE `size` carries (at least, with a whole pose)."""
        return self.sizes.trunk(size)

    def timeout_for(self, poll_frame_bytes: int, reply_frame_bytes: int) -> float:
        return self.tx_time(poll_frame_bytes) + self.tx_time(reply_frame_bytes) + 2 * self.delay_s + self.margin_s

    def deadline(self) -> float | None:
        """When the awaited reply counts as lost; None if the token is ours."""
        if self._awaiting is None:
            return None
        sent_at, poll, reply_bytes = self._awaiting
        deadline = sent_at + self.timeout_for(self.sizes.poll(poll), reply_bytes)
        if self.quick_after_loss and self._lost_last:
            # After a lost reply (version 2, §8.1) the poll asks for no image data and
            # waits with the shortest margin §5 allows: a run of lost polls leaves the
            # ROV without one for less time (its failsafe).
            deadline -= max(0.0, self.margin_s - OUTAGE_MARGIN_S)
        return deadline

    @property
    def awaiting_reply(self) -> bool:
        return self._awaiting is not None

    def release_token(self, now: float) -> bool:
        """Whether the token is ours at `now`: no poll awaits its reply, or its
        deadline has passed (then the reply is counted lost, `ReplyLost`)."""
        if self._awaiting is None:
            return True
        deadline = self.deadline()
        assert deadline is not None
        if now < deadline:
            return False
        self._reply_lost(now)
        return True

    # ------------------------------------------------------------------
    # Sending
    # ------------------------------------------------------------------

    def next_poll(self, now: float) -> bytes | None:
        """The next poll frame if the token is ours at `now`, else None."""
        if not self.release_token(now):
            return None
        poll, order_ids = self._build_poll(now)
        frame = encode_frame(poll.encode())
        self._events.append(PollSent(now, frame, poll, order_ids))
        expected = self._expected_reply_bytes(poll)
        # §1 (1.1): no reply longer than this poll's SIZE allows is a start.
        self.decoder.max_len = min(self.reply_frame_bytes(poll.size) - OVERHEAD, MAX_FRAME - OVERHEAD)
        self._awaiting = (now, poll, expected)
        self.stats.polls_sent += 1
        self.stats.bytes_sent += len(frame)
        if poll.wants_image and self._image.started_at is None:
            self._image.started_at = now
            self.stats.images_started += 1
        return frame

    def take_events(self) -> list[object]:
        """Events raised outside `receive` (timeouts, cancellations)."""
        events, self._events = self._events, []
        return events

    def _build_poll(self, now: float) -> tuple[Poll, tuple[int, ...]]:
        order: object = self._soft_state(now)
        order_ids: tuple[int, ...] = ()
        seq = self._ack if self._ack is not None else 0
        if self._stop is not None:
            if self._ack is not None:
                order = Stop()  # not sequenced: SEQ = ACK (§2)
                order_ids = tuple(self._stop.order_ids)
                self._reference_unset = True  # the ROV's ARM/MODE reference is reset by it
        elif self._orders and self._may_send_orders(now):
            pending = self._orders[0]
            if not pending.sent:
                pending.sent = True
                pending.seq = 1 - self._ack
                self._wish_turn = False
                if isinstance(pending.order, ImageSettings):
                    self.images_enabled = pending.order.budget_bytes > 0
                    self._next_image("settings changed")
            if not self._wish_turn:
                order = pending.order
                order_ids = (pending.order_id,)
                seq = pending.seq
            self._wish_turn = not self._wish_turn
        if isinstance(order, Velocity):
            if self._nobodys_neutral(order):
                order = self._nobodys_poll()
            elif self._recentre_owed and self._last_reply is not None and self._last_reply.hold \
                    and not self._lost_last:
                # (after a lost reply, not until a reply says whether the ROV failed safe
                # meanwhile: a re-centring from before a failsafe is not one for its HOLD)
                order = Velocity(0, 0, 0, 0, order.arm, order.mode)
        if isinstance(order, Velocity) and self.repeat_by_none and not order.arm and not order.mode \
                and order == self._velocity_taken:
            order = NoOrder()  # the ROV repeats the wish of the poll the chained reply answered
        size = self._choose_size(now)
        if self.quick_after_loss and self._lost_last:
            img, offset = self._image.img, NO_IMAGE_DATA  # a short cycle: the link is answered or lost sooner
        elif self.images_enabled:
            img, offset = self._image.img, min(len(self._image.data), NO_IMAGE_DATA - 1)
        else:
            img, offset = self._image.img, NO_IMAGE_DATA
        return Poll(seq=seq, size=size, order=order, img=img, offset=offset), order_ids  # type: ignore[arg-type]

    def _nobodys_neutral(self, wish: Velocity) -> bool:
        """A neutral wish with no request, of nobody's input, while the ROV holds or
        may hold (before any reply, and after a lost one: after a link outage the
        last reply is from before the failsafe's HOLD): sent as NONE, so that it
        releases no HOLD."""
        if self.pilot_in_force or not wish.is_neutral or wish.arm or wish.mode:
            return False
        if any(r is not None for r in self._requests.values()):
            return False  # an ARM/MODE request rides in VELOCITY polls (the first sets the reference)
        return self._last_reply is None or self._last_reply.hold or self._lost_last

    def _nobodys_poll(self) -> NoOrder | Velocity:
        """What nobody's neutral goes out as.  In version 2 (§8.1) a NONE chained to a
        reply with a wish repeats that wish, so (§5, decided): when the chained reply
        showed no HOLD, four zero axes, that stop the vehicle (in version 2 no HOLD the
        operator has not seen can be on the ROV while it takes a poll on such a reply);
        under HOLD the wish it repeats is a non-zero one, ignored there."""
        if self.repeat_by_none and self._velocity_taken is not None \
                and self._last_reply is not None and not self._last_reply.hold:
            return Velocity()
        return NoOrder()

    def _may_send_orders(self, now: float) -> bool:
        """§3: no one-shot order until `start_wait_s` after the first reply."""
        return self._first_reply_at is not None and now - self._first_reply_at >= self.start_wait_s

    def _soft_state(self, now: float) -> Velocity:
        fields = {"arm": Arm.NONE, "mode": Mode.KEEP}
        for what, request in self._requests.items():
            if request is None:
                continue
            value, since, needs_gap = request
            if needs_gap:
                continue  # 0 until a reply to a poll with 0 comes
            if self._stop is not None and self._ack is not None:
                # §2 (decided): the polls carry the STOP, not the request; its 3 s begin
                # with the first VELOCITY after it (a disarm asked during a STOP is sent).
                request[1] = now
                continue
            if self._reference_unset and not (what == "arm" and value == Arm.DISARM):
                request[1] = now  # held back: its 3 s start when it goes out
                continue
            if now - since > self.request_hold_s:
                self._requests[what] = None
                self._events.append(RequestExpired(what))
            else:
                fields[what] = value
        w = self._wish
        return Velocity(w.vx, w.vy, w.vz, w.vyaw, fields["arm"], fields["mode"])

    def steering(self, now: float) -> bool:
        return not self._wish.is_neutral or now - self._wish_changed_at < self.steer_hold_s

    def _choose_size(self, now: float) -> int:
        if self.steering(now) or self._stop is not None:
            # A STOP's answer comes as fast as a steering poll's (its reply short).
            size = self.steering_size
        elif self.attended and now - self._wish_changed_at < self.react_window_s:
            # A pilot who paused is likely to steer again soon: the first wish after
            # the pause reaches the ROV within a steering cycle.
            size = self.steering_size
        elif self.attended:
            # Watching: a reply short enough that the pose shown stays fresh.
            size = min(self.attended_size, self._best_size_for_error_rate())
        elif self.idle_size is not None:
            size = self.idle_size
        else:
            size = self._best_size_for_error_rate()
        return size

    def estimated_ber(self) -> float:
        """Bit error rate inferred from lost cycles (0 until something is lost)."""
        if self._ewma_n <= 0 or self._ewma_lost <= 0:
            return 0.0
        loss = min(self._ewma_lost / self._ewma_n, 0.999)
        bits = self._ewma_bits / self._ewma_n
        return 1.0 - (1.0 - loss) ** (1.0 / max(bits, 1.0))

    def _best_size_for_error_rate(self) -> int:
        ber = self.estimated_ber()
        poll_bytes = self.sizes.velocity_poll()
        best, best_rate = 3, -1.0
        for size in range(4):
            reply = self.reply_frame_bytes(size)
            trunk = self.sizes.trunk(size)
            p_ok = (1.0 - ber) ** (8 * (poll_bytes + reply))
            cycle = self.timeout_for(poll_bytes, reply) - self.margin_s
            # A lost cycle costs the full timeout instead of the cycle.
            expected_time = p_ok * cycle + (1 - p_ok) * (cycle + self.margin_s)
            rate = trunk * p_ok / expected_time
            if rate > best_rate * 1.02:  # prefer larger trunks unless clearly worse
                best, best_rate = size, rate
        return best

    def _expected_reply_bytes(self, poll: Poll) -> int:
        if not poll.wants_image:
            return self.sizes.reply_without_image()
        return self.reply_frame_bytes(poll.size)

    def _observe_cycle(self, lost: bool, bits: int) -> None:
        decay = 0.95
        self._ewma_lost = self._ewma_lost * decay + (1.0 if lost else 0.0)
        self._ewma_bits = self._ewma_bits * decay + bits
        self._ewma_n = self._ewma_n * decay + 1.0

    # ------------------------------------------------------------------
    # Receiving
    # ------------------------------------------------------------------

    def receive_bytes(self, data: bytes, now: float) -> list[object]:
        """Feed raw received bytes; returns the events of the replies they completed."""
        self.stats.bytes_received += len(data)
        events: list[object] = []
        for payload in self.decoder.feed(data):
            events.extend(self.receive(payload, now))
        return events

    def _report(self, reply: Reply, now: float, frame_bytes: int | None, round_trip_s: float | None) -> VehicleReport:
        return report_from_reply(reply, arrived_at=now, frame_bytes=frame_bytes, bitrate_bps=self.bitrate_bps,
                                 delay_s=self.delay_s, round_trip_s=round_trip_s)

    def receive(self, payload: bytes, now: float, frame_bytes: int | None = None) -> list[object]:
        """Consume one reply payload (a frame whose CRC held).  `frame_bytes`: the
        frame that carried it, when it was not this payload's 1.1 frame (version 2)."""
        try:
            reply = Reply.decode(payload)
        except ProtocolError:
            self.stats.protocol_errors += 1
            return self.take_events()
        events = self.take_events()
        round_trip = None
        poll: Poll | None = None
        if self._awaiting is not None:
            sent_at, poll, _ = self._awaiting
            round_trip = now - sent_at
            self._lost_last = False
            if isinstance(poll.order, Velocity):
                v = poll.order
                self._velocity_taken = v if not v.arm and not v.mode else None
            elif not isinstance(poll.order, NoOrder):
                self._velocity_taken = None  # a one-shot order or a STOP: no wish repeated after it
            bits = 8 * (self.sizes.poll(poll) + OVERHEAD + len(payload))
            self._observe_cycle(False, bits)
            self._awaiting = None
        self.stats.replies += 1
        self.stats.last_round_trip_s = round_trip
        self._last_reply = reply
        if self._first_reply_at is None:
            self._first_reply_at = now
        events.append(PoseReceived(reply, now, round_trip, self._report(reply, now, frame_bytes, round_trip)))
        events.extend(self._update_ack(reply, now))
        events.extend(self._update_stop(reply, poll, now))
        self._update_requests(reply, poll, now)
        events.extend(self._take_trunk(reply, now))
        events.extend(self.take_events())
        return events

    def on_sync(self, payload: bytes, restarted: bool, now: float, round_trip_s: float | None = None,
                frame_bytes: int | None = None) -> list[object]:
        """Version 2 (§8): a SYNC reply to our HELLO (the chain paired them),
        with `restarted` when its BOOT differs from the last one.  It answers
        the HELLO, not a poll: it shows the ROV's status and gives its ACK,
        but confirms no STOP, settles no order and clears no ARM/MODE request
        (the next reply to a poll does that: its ACK still names the same
        order).  A restarted ROV: every partial image is discarded, ACK is
        taken from the SYNC, an order sent and not answered has an unknown
        fate and is not sent again, queued orders are not sent, ARM/MODE
        requests wait for a reply to a VELOCITY poll; a STOP goes on until
        confirmed."""
        self._velocity_taken = None  # after a HELLO the ROV may have failsafed or restarted
        try:
            reply = dataclasses.replace(Reply.decode(payload, allow_sync=True), sync=False)
        except ProtocolError:
            self.stats.protocol_errors += 1
            return self.take_events()
        if restarted:
            for pending in list(self._orders):
                if pending.sent:
                    self._events.append(OrderFateUnknown(pending.order_id, pending.order, now))
                else:
                    self._events.append(OrderNotSent(pending.order_id, pending.order, "the ROV restarted"))
            self._orders.clear()
            if self._stop is not None and self._stop.orphan is not None:
                self._events.append(OrderFateUnknown(self._stop.orphan.order_id, self._stop.orphan.order, now))
                self._stop.orphan = None
            self._reference_unset = True  # a new start: its first VELOCITY sets the reference
            self._next_image("the ROV restarted")
        # The same ROV: its ACK is the one the next reply will show too, so a
        # pending order's SEQ is unchanged and that reply settles it.
        self._ack = reply.ack
        self.stats.replies += 1
        self.stats.last_round_trip_s = round_trip_s
        self._last_reply = reply
        if self._first_reply_at is None:
            self._first_reply_at = now  # §3: the 3 s start rule counts from the first SYNC
        events = self.take_events()
        events.append(PoseReceived(reply, now, round_trip_s, self._report(reply, now, frame_bytes, round_trip_s)))
        return events

    def _update_ack(self, reply: Reply, now: float) -> list[object]:
        events: list[object] = []
        if self._ack is None or not self._may_send_orders(now):
            self._ack = reply.ack  # §3: the ACK of the last reply of the first 3 s
            return events
        self._ack = reply.ack
        if self._orders and self._orders[0].sent:
            # The order in flight was sent with SEQ = not(previous ACK); its
            # outcome is known when the reply's ACK equals that SEQ.
            pending = self._orders[0]
            if reply.ack == pending.seq:
                self._orders.popleft()
                events.append(self._outcome(pending, reply, now))
        stop = self._stop
        if stop is not None and stop.orphan is not None and reply.ack == stop.orphan.seq:
            events.append(self._outcome(stop.orphan, reply, now))
            stop.orphan = None
        return events

    @staticmethod
    def _outcome(pending: _PendingOrder, reply: Reply, now: float) -> object:
        if reply.rejected:
            return OrderRejected(pending.order_id, pending.order, reply.reason, now)
        return OrderAcknowledged(pending.order_id, pending.order, now)

    def _update_stop(self, reply: Reply, poll: Poll | None, now: float) -> list[object]:
        stop = self._stop
        if stop is None or poll is None or not isinstance(poll.order, Stop):
            return []  # only a reply to a poll that carried STOP confirms it (§2)
        if reply.hold and reply.autopilot and reply.mode in (Mode.POS_HOLD, Mode.DEPTH_HOLD):
            self._stop = None
            self._settle_orphan(stop)
            events = self.take_events()
            events.extend(StopConfirmed(order_id, reply.mode, now) for order_id in stop.order_ids)
            return events
        if not reply.autopilot and not stop.not_carried_out:
            stop.not_carried_out = True
            return [StopNotCarriedOut(order_id, now) for order_id in stop.order_ids]
        if reply.autopilot:
            stop.not_carried_out = False
        return []

    def _update_requests(self, reply: Reply, poll: Poll | None, now: float) -> None:
        if reply.failsafe:
            # §5 (decided): the ROV braked and holds since a silence; a re-centring owed
            # from before it is not one for this HOLD (the stick may have moved since).
            self._recentre_owed = False
            # §2 (decided): the ROV failed safe before it took this poll, and its
            # reference went with it.  A VELOCITY poll only set it anew: a request
            # riding in it was swallowed, and goes again after a 0 (a disarm acted).
            # Any other poll set none: requests wait for a VELOCITY's reply.
            if poll is not None and isinstance(poll.order, Velocity):
                for what, value in (("arm", poll.order.arm), ("mode", poll.order.mode)):
                    request = self._requests[what]
                    if request is not None and value and value == request[0] \
                            and not (what == "arm" and value == Arm.DISARM):
                        request[2] = True
            else:
                self._reference_unset = True
        if not reply.hold or (poll is not None and isinstance(poll.order, Velocity) and poll.order.is_neutral):
            self._recentre_owed = False  # the ROV has the re-centring, or needs none
        if poll is not None and isinstance(poll.order, Velocity):
            # One poll is out at a time, so the ROV took this VELOCITY after
            # any STOP sent before it: its reference is set now.
            self._reference_unset = False
            sent = {"arm": poll.order.arm, "mode": poll.order.mode}
            for what, value in sent.items():
                self._last_seen[what] = value
                request = self._requests[what]
                if request is not None and request[2] and value == 0:
                    request[1], request[2] = now, False  # the gap is in: the request goes out now
        arm = self._requests["arm"]
        if arm is not None and not arm[2] and reply.autopilot and reply.armed == (arm[0] == Arm.ARM):
            self._requests["arm"] = None
        mode = self._requests["mode"]
        if mode is not None and not mode[2] and reply.mode == mode[0]:
            self._requests["mode"] = None

    def _take_trunk(self, reply: Reply, now: float) -> list[object]:
        if not reply.has_trunk or reply.img != self._image.img or not self.images_enabled:
            return []
        image = self._image
        assert reply.offset is not None
        events: list[object] = []
        if reply.first and image.data:
            # §4 (1.1): the ROV captured this IMG anew (it restarted, or lost
            # the image): the partial copy is of another picture.
            events.append(ImageAbandoned(image.img, len(image.data), "the ROV sent the image anew (FIRST)"))
            self.stats.images_abandoned += 1
            image.data.clear()
        if not image.add(reply.offset, reply.trunk):
            return events  # beyond the contiguous prefix: cannot happen with a conforming ROV
        total = image.total
        received = len(image.data)
        if self._images_to_skip:
            # The first image after start may be any age the ROV still held: not shown.
            if image.complete:
                self._images_to_skip -= 1
                self._image = ImageAssembly(next_img(image.img))
            return events
        events.append(ImageProgress(image.img, received, total, image.stream))
        if image.complete:
            self.stats.images_completed += 1
            started = image.started_at if image.started_at is not None else now
            events.append(ImageComplete(image.img, image.stream, started, now))
            self._image = ImageAssembly(next_img(image.img))
        return events

    def _reply_lost(self, now: float) -> None:
        assert self._awaiting is not None
        sent_at, poll, expected = self._awaiting
        self._awaiting = None
        self._lost_last = True
        self.stats.replies_lost += 1
        self._observe_cycle(True, 8 * (self.sizes.poll(poll) + expected))
        self._events.append(ReplyLost(sent_at, now))
        if not self.retransmit and poll.wants_image and self._image.data:
            self._next_image("reply lost (no retransmission)")

    def _next_image(self, reason: str) -> None:
        image = self._image
        if image.started_at is not None:
            self._images_to_skip = 0  # the next IMG is a fresh capture anyway
        if image.started_at is not None and not image.complete:
            self.stats.images_abandoned += 1
            self._events.append(ImageAbandoned(image.img, len(image.data), reason))
        self._image = ImageAssembly(next_img(image.img))

    # -- a recording's replay (link/radio/replay.py) takes its trunks by these same rules --

    def follow_request(self, poll: Poll, now: float) -> list[object]:
        """A recorded poll, as the live master made it: when it asks for image data
        of another IMG than the one held, the live master had moved on (the pilot's
        next picture, a restart, a loss without retransmission): so does this one."""
        if not poll.wants_image or not self.images_enabled:
            return []
        if poll.img != self._image.img:
            self._next_image("the recording moved on to the next picture")
            self._image = ImageAssembly(poll.img)
        if self._image.started_at is None:
            self._image.started_at = now
        return self.take_events()

    def take_trunk(self, reply: Reply, now: float) -> list[object]:
        """A recorded reply's trunk, by the rules `receive` applies (§4)."""
        return self._take_trunk(reply, now) + self.take_events()

    def abandon_image(self) -> None:
        """The pilot skips this picture (seen enough of it, or wants a fresher one): ask for the next one."""
        self._next_image(PILOT_SKIPPED)

    @property
    def last_reply(self) -> Reply | None:
        return self._last_reply

    @property
    def image_received(self) -> int:
        return len(self._image.data)
