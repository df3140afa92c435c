"""Version 2 of the link around the version 1.1 state machines (docs/PROTOCOL.md §8).

Goals: the master and the slave keep deciding everything version 1.1
decides (orders, ACK, images, failsafe); version 2 only decides which frames
exist for them.  A frame that is not authentic, is replayed, or arrives late
never reaches them.

Plan: `SecureSlave` and `SecureMaster` hold the `Slave` or `Master` they
wrap (`.slave`, `.master`) and put `link.auth`'s chain and framing between
the bytes and that machine.  Each has the methods the drivers and `SimLink`
call (`receive_bytes`, `next_poll`, `take_events`, `deadline`, `tick`, ...);
`SecureMaster` also passes the operator's wishes, orders and the figures it
shows to its master, each by a method of its own.  Anything else is read on
the machine itself:

- ROV: an authentic HELLO is answered with a SYNC (the slave's status and
  ACK, no trunk) and touches nothing else; an authentic, fresh poll goes to
  the slave as its payload, and is taken (it moves the chain) only when the
  slave answers it, i.e. when it parsed; the answer is sealed on that poll.
- Operator: sends HELLOs until a SYNC comes, and again, alternating with
  polls, after two poll timeouts (at least 2 s) without an authentic reply;
  a SYNC gives the master its ACK and status, and a new BOOT tells it that
  the ROV restarted; replies that are late or inauthentic are counted and
  dropped: the master then sees its poll unanswered, as §8 asks.

Decisions where §8 is silent:
- The SYNC is handed to the master as the answer to a HELLO (`on_sync`):
  it gives the master the ROV's status and ACK, and confirms no STOP, settles
  no order and clears no ARM/MODE request (a reply to a poll does that).
- The master's timeouts count the 5 (poll) and 4 (reply) bytes version 2
  adds: its margin grows by their air time.
- Every structural fault of a reply (§1, §8.1) is found before the chain
  moves (`parse_reply`): a reply the master would refuse is never chained to.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..scene import OP_REMOVED, ObjectRecord, SceneOutbox, SeenObject, altitude_from_code, decode_records
from .auth import (
    CHALLENGE_BYTES,
    HELLO_PAYLOAD,
    KEEP_FAILSAFES,
    NONCE_BYTES,
    SYNC_PAYLOAD,
    TAG_BYTES,
    AuthFrameDecoder,
    HelloIn,
    OperatorChain,
    PollIn,
    RovChain,
)
from .events import (
    AltitudeReported,
    InauthenticFrame,
    LateReply,
    ObjectRecordIgnored,
    ObjectRemoved,
    ObjectReported,
    Synced,
)
from .frame import frame_contents
from .master import FrameSizes, Master, MasterStats, PollSent
from .messages import (
    FAILSAFE_S,
    HELLO_BIT,
    MAX_POLL_PAYLOAD,
    NO_IMAGE_DATA,
    REPLY_HEADER,
    REPLY_STATUS_BYTE,
    ImageSettings,
    Mode,
    Poll,
    Position,
    ProtocolError,
    Reply,
    ReservedOrder,
    Stop,
)
from .slave import Slave, SlaveOutput
from .wire2 import (
    ANNEX_MAX,
    MIN_POLL_FRAME,
    NO_CONTINUATION,
    POSE_BYTES,
    RECORD_EVERY,
    REJECTED_BIT,
    V2_MAX_FRAME,
    V2_OVERHEAD,
    V2_REPLY_STATUS,
    Pose,
    annex_bytes,
    continuation_of,
    frame2_contents,
    poll_from_wire,
    poll_to_wire,
    pose_of,
    pose_wire_bytes,
    reply_frame_cap,
    reply_from_wire_annex,
    reply_to_wire,
    request_of,
    trunk_room,
    wish_of,
)

POLL_EXTRA = 1 + TAG_BYTES  # COUNT, TAG
_NO_ORDER = Poll().encode()  # SEQ 0, SIZE 0, ORDER NONE, no image data
HELLO_POLL = bytes((_NO_ORDER[0] | HELLO_BIT,)) + _NO_ORDER[1:]  # a HELLO before its CHALLENGE
HELLO_FRAME_BYTES = V2_OVERHEAD + HELLO_PAYLOAD + CHALLENGE_BYTES + TAG_BYTES
SYNC_FRAME_BYTES = V2_OVERHEAD + SYNC_PAYLOAD + NONCE_BYTES + TAG_BYTES
MAX_POLL_LEN = MAX_POLL_PAYLOAD + POLL_EXTRA  # the largest poll (POSITION), or a HELLO (15)


class FrameSizes2(FrameSizes):
    """Version 2's frame lengths (§8.1) for the master's timeouts and SIZE choice:
    no CRC, COUNT and TAG on a poll, a reply frame capped by its SIZE class."""

    def poll(self, poll: Poll) -> int:
        return V2_OVERHEAD + len(poll.encode()) + POLL_EXTRA  # at most: the request may be left out

    def reply(self, size: int) -> int:
        return reply_frame_cap(size, self.max_frame)

    def reply_without_image(self) -> int:
        return V2_OVERHEAD + V2_REPLY_STATUS + POSE_BYTES + ANNEX_MAX + TAG_BYTES

    def trunk(self, size: int) -> int:
        return trunk_room(size, self.max_frame, POSE_BYTES, TAG_BYTES, self.velocity_poll())

    def velocity_poll(self) -> int:
        return V2_OVERHEAD + 1 + 4 + POLL_EXTRA  # the four axes, the request continued


def poll_sent_from_frame(frame: bytes, at: float, *, version: str, poll: bytes | None = None) -> PollSent | None:
    """A recorded poll frame as the master said it sent it (a replay has frames,
    not events; no order ids); None for bytes that are no poll.  `poll`: the
    version 1.1 payload the master made, which a version 2 recording keeps beside
    its frame (the frame may leave its image request out, §8.1)."""
    contents = frame_contents(frame)
    if version == "2":
        contents = frame2_contents(frame)
        if contents and contents[0] & HELLO_BIT:
            return PollSent(at, frame, None)
        if poll is None:
            return None
        contents = poll
    try:
        return PollSent(at, frame, Poll.decode(contents))
    except ProtocolError:
        return None


def parse_reply(payload: bytes, poll11: bytes | None,
                reference: Pose | None) -> tuple[bytes, tuple[int, int], Pose, int | None, bytes]:
    """A timely reply's version 1.1 payload (a SYNC's when `poll11` is None), what
    it leaves for the next poll (§8.1), and its annex (§11.1: the ALT byte or None,
    an object record's bytes).  Every structural fault (§1) raises ProtocolError
    here, before the chain moves: a reply the master would refuse is never chained to."""
    if poll11 is None:
        Reply.decode(payload, allow_sync=True)
        return payload, NO_CONTINUATION, pose_of(payload), None, b""
    reply, pose, alt, record = reply_from_wire_annex(payload, request_of(poll11), reference)
    Reply.decode(reply)
    return reply, continuation_of(reply, poll11), pose, alt, record


@dataclass
class SecureStats:
    hellos_sent: int = 0
    syncs: int = 0
    inauthentic: int = 0
    late: int = 0
    restarts_seen: int = 0
    records_ignored: int = 0  # §11 object records out of range


class SecureSlave:
    """Version 2 in front of a `Slave`.  The drivers call `receive_bytes`,
    `tick`, `order_outcome` (SimLink's autopilot) and `failsafe_at`; the ROV
    node keeps the slave itself (`.slave`) for the rest."""

    def __init__(self, slave: Slave, key: bytes, *, boot: bytes | None = None) -> None:
        self.slave = slave
        # §8.1: a SIZE class caps the reply frame, tag and pose included, and so
        # does the link's maximum frame size.
        _check_max_frame(slave.max_frame)
        self.max_frame = min(slave.max_frame, V2_MAX_FRAME)
        self._pose_bytes = POSE_BYTES  # the pose of the reply being made
        self._poll_frame = MIN_POLL_FRAME  # the frame of the poll it answers
        slave.trunk_room = lambda size: trunk_room(size, self.max_frame, self._pose_bytes, TAG_BYTES,
                                                   self._poll_frame)
        self.chain = RovChain(key, failsafe_s=slave.failsafe_s, boot=boot)
        self.decoder = AuthFrameDecoder(self.chain.is_authentic, max_len=MAX_POLL_LEN)
        # §11.1: the altitude and the objects, in the replies' annex.
        self.scene = SceneOutbox()
        self._picture_replies = 0  # replies carrying picture data since the last record in one

    # -- what the drivers call besides receive_bytes ------------------------

    def tick(self, now: float) -> list[object]:
        return self.slave.tick(now)

    def order_outcome(self, token: int, accepted: bool, reason: int | None = None, now: float = 0.0) -> list[object]:
        return self.slave.order_outcome(token, accepted, reason, now)

    @property
    def failsafe_at(self) -> float | None:
        return self.slave.failsafe_at

    def _annex(self, poll11: bytes, now: float) -> tuple[int | None, ObjectRecord | None]:
        """What this reply tells of the scene (§11.1): the ALT byte when due, and the next
        object record, which in a reply carrying picture data waits for every
        RECORD_EVERY-th one (pictures give objects at most one record in that many)."""
        alt = self.scene.altitude_due(now)
        record = None
        asks_picture = request_of(poll11)[1] != NO_IMAGE_DATA
        if self.scene.pending() and (not asks_picture or self._picture_replies + 1 >= RECORD_EVERY):
            record = self.scene.next_record()
        return alt, record

    def _told(self, alt: int | None, record: ObjectRecord | None, at: float) -> None:
        if alt is not None:
            self.scene.altitude_delivered(alt, at)
        if record is not None:
            self.scene.delivered(record)

    def _sync_payload(self) -> bytes:
        status = self.slave.status
        reply = Reply(**{k: getattr(status, k) for k in status.__dataclass_fields__}, ack=self.slave.ack,
                      failsafe=self.slave.failsafe, hold=self.slave.hold, rejected=self.slave.rejected,
                      reason=self.slave.reason, sync=True)
        return reply.encode()

    def receive_bytes(self, data: bytes, now: float) -> SlaveOutput:
        out = SlaveOutput(events=self.slave.tick(now))
        replies = []
        before = self.decoder.counters.inauthentic
        for contents in self.decoder.feed(data):
            bad_hellos = self.chain.counters.bad_hellos
            got = self.chain.check_poll(contents, now)
            if got is None and self.chain.counters.bad_hellos != bad_hellos:
                self.slave.stats.protocol_errors += 1  # a HELLO with an order: authentic, not answered
            elif isinstance(got, HelloIn):
                sync = self._sync_payload()
                self.scene.forget_operator()  # a new chain: the operator holds none of the scene
                replies.append(self.chain.seal_sync(sync, got, now, info=(NO_CONTINUATION, pose_of(sync), None, None)))
            elif isinstance(got, PollIn):
                continuation, reference, wish, told = (got.info if got.info is not None
                                                       else (NO_CONTINUATION, None, None, None))
                try:
                    poll = poll_from_wire(got.payload, continuation, wish)
                except ProtocolError:
                    self.slave.stats.protocol_errors += 1  # authentic, no layout: never answered, not taken
                    continue
                if told is not None:  # the reply this poll is chained to arrived: what it told is held
                    self._told(*told)
                s = self.slave.status
                self._poll_frame = V2_OVERHEAD + len(contents)
                alt, record = self._annex(poll, now)
                self._pose_bytes = pose_wire_bytes(
                    (s.x_cm, s.y_cm, s.z_cm, s.roll_cdeg, s.pitch_cdeg, s.yaw_cdeg), reference
                ) + annex_bytes(alt, record.encode() if record else b"")
                one = self.slave.receive(poll, now)
                out.events.extend(one.events)
                if one.reply:  # it parsed: the poll is taken
                    self.chain.take(got, now)
                    reply = frame_contents(one.reply)
                    if reply[REPLY_STATUS_BYTE] & REJECTED_BIT:
                        alt, record = None, None  # no annex in a REJECTED reply: told in the next
                    if len(reply) > REPLY_HEADER and record is not None:
                        self._picture_replies = 0
                    elif len(reply) > REPLY_HEADER:
                        self._picture_replies += 1
                    replies.append(self.chain.seal_reply(
                        reply_to_wire(reply, reference, alt, record.encode() if record else b""), got, now,
                        info=(continuation_of(reply, poll), pose_of(reply), wish_of(poll), (alt, record, now))))
            else:
                out.events.append(InauthenticFrame("poll"))
        out.events.extend(InauthenticFrame("poll") for _ in range(self.decoder.counters.inauthentic - before))
        out.reply = b"".join(replies) or None
        return out


class SecureMaster:
    """Version 2 in front of a `Master`.  The drivers call `next_poll`,
    `take_events`, `deadline` and `receive_bytes`; the operator's wishes and
    orders, and the figures it shows, go to the master by the methods below
    of the same names; anything else is read on the master itself (`.master`)."""

    def __init__(self, master: Master, key: bytes) -> None:
        self.master = master
        # §8.1: version 2's frames, for the master's timeouts and SIZE choice.
        _check_max_frame(master.max_frame)
        master.sizes = FrameSizes2(min(master.max_frame, V2_MAX_FRAME))
        master.repeat_by_none = True
        master.quick_after_loss = True
        self.chain = OperatorChain(key)
        self.rov_failsafe_s = FAILSAFE_S  # the ROV's failsafe time (its setting; the console may know it)
        self.decoder = AuthFrameDecoder(self.chain.is_authentic, max_len=self._max_reply_len)
        self.stats2 = SecureStats()
        self._hello_deadline: float | None = None  # a HELLO holds the token until then
        self._last_was_hello = False
        self._events: list[object] = []
        self._last_size = 3
        self._boot: bytes | None = None
        # §8.1: what the reply (or SYNC) the next poll is chained to leaves for
        # it: where the picture continues (None: unknown, so the request is
        # always sent) and the pose the next reply's differences start from.
        self._continuation: tuple[int, int] | None = NO_CONTINUATION
        self._reference: Pose | None = None
        self._sent: dict[int, tuple[bytes, Pose | None]] = {}  # poll number -> (1.1 payload, reference)
        # Called with (payload, sync, now) for every authentic, timely reply
        # handed to the master: what a recording must keep to be replayed.
        self.on_reply = None

    # -- the operator's wishes and orders, and what it shows: the master's --

    def set_velocity(self, vx: int, vy: int, vz: int, vyaw: int, now: float) -> None:
        self.master.set_velocity(vx, vy, vz, vyaw, now)

    def set_pilot_in_force(self, in_force: bool) -> None:
        self.master.set_pilot_in_force(in_force)

    def set_attended(self, attended: bool) -> None:
        self.master.set_attended(attended)

    def recentred(self) -> None:
        self.master.recentred()

    def request_arm(self, arm: bool, now: float) -> None:
        self.master.request_arm(arm, now)

    def request_mode(self, mode: Mode | int, now: float) -> None:
        self.master.request_mode(mode, now)

    def send_order(self, order: Position | ImageSettings | Stop | ReservedOrder) -> int:
        return self.master.send_order(order)

    def cancel_stop(self) -> bool:
        return self.master.cancel_stop()

    def abandon_image(self) -> None:
        self.master.abandon_image()

    @property
    def stopping(self) -> bool:
        return self.master.stopping

    @property
    def stats(self) -> MasterStats:
        """The master's counters (version 2's own: `stats2`)."""
        return self.master.stats

    def estimated_ber(self) -> float:
        return self.master.estimated_ber()

    def reply_frame_bytes(self, size: int) -> int:
        return self.master.reply_frame_bytes(size)

    def trunk_bytes(self, size: int) -> int:
        return self.master.trunk_bytes(size)

    # -- timing -------------------------------------------------------------

    def hello_timeout(self) -> float:
        m = self.master
        return m.tx_time(HELLO_FRAME_BYTES) + m.tx_time(SYNC_FRAME_BYTES) + 2 * m.delay_s + m.margin_s

    def _poll_timeout(self) -> float:
        m = self.master
        return m.timeout_for(V2_OVERHEAD + MAX_POLL_PAYLOAD + POLL_EXTRA, m.reply_frame_bytes(self._last_size))

    def deadline(self) -> float | None:
        if self._hello_deadline is not None:
            return self._hello_deadline
        return self.master.deadline()

    def _silent_too_long(self, now: float) -> bool:
        """§8.1: no authentic reply for so long that the ROV may no longer keep the
        chain value the polls are made on (twice its failsafe time, less two poll
        timeouts), or may have restarted: HELLOs then alternate with polls."""
        heard = self.chain.last_authentic_at
        silent = max(2.0, KEEP_FAILSAFES * self.rov_failsafe_s - 2 * self._poll_timeout())
        return heard is not None and now - heard > silent

    def _max_reply_len(self) -> int:
        m = self.master
        return max(SYNC_FRAME_BYTES, m.reply_frame_bytes(self._last_size)) - V2_OVERHEAD

    # -- sending -----------------------------------------------------------

    def next_poll(self, now: float) -> bytes | None:
        # The token rule (§2) holds for HELLOs too: nothing goes out while a
        # poll or a HELLO awaits its answer or its deadline.
        if self._hello_deadline is not None:
            if now < self._hello_deadline:
                return None
            self._hello_deadline = None  # no SYNC in time
        if not self.master.release_token(now):
            return None
        hello = not self.chain.synced or (self._silent_too_long(now) and not self._last_was_hello)
        if hello:
            self._last_was_hello = True
            self._hello_deadline = now + self.hello_timeout()
            self.stats2.hellos_sent += 1
            hello = self.chain.seal_hello(HELLO_POLL, now, deadline=self._hello_deadline)
            self._events.append(PollSent(now, hello, None))
            return hello
        frame = self.master.next_poll(now)
        if frame is None:
            return None
        self._last_was_hello = False
        payload = frame_contents(frame)
        self._last_size = Poll.decode_header(payload)[1]
        number = self.chain.next_number
        sealed = self.chain.seal_poll(poll_to_wire(payload, self._continuation), now, deadline=self.master.deadline())
        self._sent[number] = (payload, self._reference)
        self._sent.pop(number - 16, None)
        # The master said what it sent: the frame that left is the sealed one.
        self._events.extend(dataclasses.replace(e, frame=sealed) if isinstance(e, PollSent) else e
                            for e in self.master.take_events())
        return sealed

    def take_events(self) -> list[object]:
        events, self._events = self._events, []
        return events + self.master.take_events()

    # -- receiving ---------------------------------------------------------

    def _parse(self, payload: bytes, sync: bool, answers: int):
        if sync:
            return parse_reply(payload, None, None)
        sent = self._sent.get(answers)
        if sent is None:
            raise ProtocolError("a reply to a poll no longer kept")
        return parse_reply(payload, *sent)

    def receive_bytes(self, data: bytes, now: float) -> list[object]:
        self.master.stats.bytes_received += len(data)
        events: list[object] = []
        before = self.decoder.counters.inauthentic
        for contents in self.decoder.feed(data):
            events.extend(self.receive(contents, now))
        forged = self.decoder.counters.inauthentic - before
        self.stats2.inauthentic += forged
        events.extend(InauthenticFrame("reply") for _ in range(forged))
        return events

    def receive(self, contents: bytes, now: float) -> list[object]:
        """One frame's contents.  The chain pairs it with the poll or HELLO it
        answers: only an answer to the last one sent, within that frame's own
        deadline, reaches the master (a SYNC as a SYNC, never as the answer
        to a poll); anything else is late and confirms nothing."""
        got = self.chain.open_reply(contents, now, self._parse)
        if got is None:
            self.stats2.inauthentic += 1
            return [InauthenticFrame("reply")]
        if got.late:
            self.stats2.late += 1
            return [LateReply(got.sync)]
        if got.malformed:
            self.master.stats.protocol_errors += 1  # authentic, but no reply: counted, its poll unanswered
            return self.master.take_events()
        payload, self._continuation, self._reference, alt, record = got.parsed  # type: ignore[misc]
        if self.on_reply is not None:
            self.on_reply(payload, got.sync, now)
        frame_bytes = V2_OVERHEAD + len(contents)  # what arrived, not the 1.1 payload rebuilt from it
        if not got.sync:
            return self.master.receive(payload, now, frame_bytes) + self._scene_events(alt, record, now)
        self._hello_deadline = None  # the HELLO is answered: the token is ours
        first = self.stats2.syncs == 0
        restarted = not first and got.boot != self._boot
        self._boot = got.boot
        self.stats2.syncs += 1
        self.stats2.restarts_seen += restarted
        # A new chain: the ROV tells its altitude afresh (§11.1), unknown until then.
        events: list[object] = [Synced(got.boot, restarted, first), AltitudeReported(now, None, 0)]
        events.extend(self.master.on_sync(got.payload, restarted, now, now - got.sent_at, frame_bytes))
        return events


    def _scene_events(self, alt: int | None, record: bytes, now: float) -> list[object]:
        """§11.1's annex as events: the altitude, an object new, changed or removed, or a
        record out of range (counted and ignored)."""
        events: list[object] = []
        if alt is not None:
            events.append(AltitudeReported(now, altitude_from_code(alt), alt))
        if record:
            records, dropped = decode_records(record)
            for r in records:
                events.append(ObjectRemoved(now, r.object_id) if r.op == OP_REMOVED
                              else ObjectReported(now, SeenObject.from_record(r), len(record)))
            if dropped:
                self.stats2.records_ignored += dropped
                events.append(ObjectRecordIgnored(now, record.hex(" ")))
        return events


def _check_max_frame(max_frame: int) -> None:
    if max_frame < SYNC_FRAME_BYTES:
        raise ValueError(f"version 2 needs a maximum frame size of at least {SYNC_FRAME_BYTES} bytes "
                         f"(a SYNC reply), got {max_frame}")
