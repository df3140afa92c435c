"""Version 2 of the link around the version 1.1 state machines (docs/PROTOCOL.md §8).

Goals: the master and the slave keep deciding everything version 1.1
decides (orders, ACK, images, failsafe); version 2 only decides which frames
exist for them.  A frame that is not authentic, is replayed, or arrives late
never reaches them.

Plan: `SecureSlave` and `SecureMaster` have the interface of `Slave` and
`Master` that the drivers and `SimLink` use (`receive_bytes`, `next_poll`,
`take_events`, `deadline`, `tick`, ...; everything else is passed through),
and put `link.auth`'s chain and framing between the bytes and the machine
they wrap:

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
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .auth import (
    HELLO_BIT,
    SYNC_BIT,
    TAG_BYTES,
    AuthFrameDecoder,
    HelloIn,
    OperatorChain,
    PollIn,
    RovChain,
)
from .frame import MAX_FRAME, OVERHEAD
from .master import PollSent
from .messages import Poll, ProtocolError

POLL_EXTRA = 1 + TAG_BYTES  # COUNT, TAG
REPLY_EXTRA = TAG_BYTES
HELLO_PAYLOAD = bytes((HELLO_BIT, 0x1F, 0xFF))  # SEQ 0, SIZE 0, ORDER NONE, no image data
HELLO_FRAME_BYTES = OVERHEAD + 3 + 8 + TAG_BYTES
SYNC_FRAME_BYTES = OVERHEAD + 14 + 12 + TAG_BYTES
MAX_POLL_LEN = 3 + 9 + POLL_EXTRA  # the largest poll (POSITION), or a HELLO (15)


def poll_sent_from_frame(frame: bytes, at: float, *, version: str) -> PollSent | None:
    """A recorded poll frame as the master said it sent it (a replay has frames,
    not events; no order ids); None for bytes that are no poll."""
    contents = frame[2:-2]
    if version == "2":
        if contents and contents[0] & HELLO_BIT:
            return PollSent(at, frame, None)
        contents = contents[:-POLL_EXTRA]
    try:
        return PollSent(at, frame, Poll.decode(contents))
    except ProtocolError:
        return None


@dataclass(frozen=True)
class InauthenticFrame:
    """A frame whose CRC held but whose tag no kept chain value makes (counted, dropped)."""

    side: str  # "reply" (operator) or "poll" (ROV)


@dataclass(frozen=True)
class LateReply:
    """An authentic reply to a poll already answered, older than one answered, or past its timeout."""

    sync: bool


@dataclass(frozen=True)
class Synced:
    """A SYNC taken: the chain is (re)started; `restarted` when the ROV's BOOT changed."""

    boot: bytes
    restarted: bool
    first: bool


@dataclass
class SecureStats:
    hellos_sent: int = 0
    syncs: int = 0
    inauthentic: int = 0
    late: int = 0
    restarts_seen: int = 0


class _Wrapper:
    """Reads and writes of anything but the wrapper's own attributes go to the wrapped machine."""

    _own: frozenset = frozenset()

    def __getattr__(self, name):
        return getattr(self.__dict__["_inner"], name)

    def __setattr__(self, name, value) -> None:
        if name in self._own or "_inner" not in self.__dict__:
            object.__setattr__(self, name, value)
        else:
            setattr(self._inner, name, value)


class SecureSlave(_Wrapper):
    _own = frozenset({"slave", "chain", "decoder"})

    def __init__(self, slave, key: bytes, *, boot: bytes | None = None) -> None:
        object.__setattr__(self, "_inner", slave)
        self.slave = slave
        # A reply's frame holds the tag too (§8: SIZE 3 is 235 bytes in version 2,
        # and a link's maximum frame size counts the tag).
        _check_max_frame(slave.max_frame)
        slave.max_frame = min(slave.max_frame, MAX_FRAME) - REPLY_EXTRA
        self.chain = RovChain(key, failsafe_s=slave.failsafe_s, boot=boot)
        self.decoder = AuthFrameDecoder(self.chain.is_authentic, max_len=MAX_POLL_LEN)

    def _sync_payload(self) -> bytes:
        from .messages import Reply

        status = self.slave.status
        reply = Reply(**{k: getattr(status, k) for k in status.__dataclass_fields__}, ack=self.slave.ack,
                      failsafe=self.slave.failsafe, hold=self.slave.hold, rejected=self.slave.rejected,
                      reason=self.slave.reason)
        payload = bytearray(reply.encode())
        payload[13] |= SYNC_BIT
        return bytes(payload)

    def receive_bytes(self, data: bytes, now: float):
        from .slave import SlaveOutput

        out = SlaveOutput(events=self.slave.tick(now))
        replies = []
        before = self.decoder.counters.inauthentic
        for contents in self.decoder.feed(data):
            bad_hellos = self.chain.counters.bad_hellos
            got = self.chain.check_poll(contents, now)
            if got is None and self.chain.counters.bad_hellos != bad_hellos:
                self.slave.stats.protocol_errors += 1  # a HELLO with an order: authentic, not answered
            elif isinstance(got, HelloIn):
                replies.append(self.chain.seal_sync(self._sync_payload(), got, now))
            elif isinstance(got, PollIn):
                one = self.slave.receive(got.payload, now)
                out.events.extend(one.events)
                if one.reply:  # it parsed: the poll is taken
                    self.chain.take(got, now)
                    replies.append(self.chain.seal_reply(one.reply[2:-2], got, now))
            else:
                out.events.append(InauthenticFrame("poll"))
        out.events.extend(InauthenticFrame("poll") for _ in range(self.decoder.counters.inauthentic - before))
        out.reply = b"".join(replies) or None
        return out


class SecureMaster(_Wrapper):
    _own = frozenset({"master", "chain", "decoder", "stats2", "_hello_deadline", "_last_was_hello", "_events",
                      "_last_size", "_boot", "next_poll", "on_reply"})

    def __init__(self, master, key: bytes) -> None:
        object.__setattr__(self, "_inner", master)
        self.master = master
        master.margin_s += master.tx_time(POLL_EXTRA + REPLY_EXTRA)
        # §8: the link's maximum frame size counts the tag, so the trunks the
        # slave sends are 4 bytes shorter (SIZE 3: 235 bytes).
        _check_max_frame(master.max_frame)
        master.max_frame = min(master.max_frame, MAX_FRAME) - REPLY_EXTRA
        self.chain = OperatorChain(key)
        self.decoder = AuthFrameDecoder(self.chain.is_authentic, max_len=self._max_reply_len)
        self.stats2 = SecureStats()
        self._hello_deadline: float | None = None  # a HELLO holds the token until then
        self._last_was_hello = False
        self._events: list[object] = []
        self._last_size = 3
        self._boot: bytes | None = None
        # Called with (payload, sync, now) for every authentic, timely reply
        # handed to the master: what a recording must keep to be replayed.
        self.on_reply = None

    # -- timing -------------------------------------------------------------

    def hello_timeout(self) -> float:
        m = self.master
        return m.tx_time(HELLO_FRAME_BYTES) + m.tx_time(SYNC_FRAME_BYTES) + 2 * m.delay_s + m.margin_s

    def _poll_timeout(self) -> float:
        m = self.master
        return m.timeout_for(OVERHEAD + 12 + POLL_EXTRA, m.reply_frame_bytes(self._last_size) + REPLY_EXTRA)

    def deadline(self) -> float | None:
        if self._hello_deadline is not None:
            return self._hello_deadline
        return self.master.deadline()

    def _silent_too_long(self, now: float) -> bool:
        heard = self.chain.last_authentic_at
        return heard is not None and now - heard > max(2.0, 2 * self._poll_timeout())

    def _max_reply_len(self) -> int:
        m = self.master
        return max(SYNC_FRAME_BYTES, m.reply_frame_bytes(self._last_size) + REPLY_EXTRA) - OVERHEAD

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
            hello = self.chain.seal_hello(HELLO_PAYLOAD, now, deadline=self._hello_deadline)
            self._events.append(PollSent(now, hello, None))
            return hello
        frame = self.master.next_poll(now)
        if frame is None:
            return None
        self._last_was_hello = False
        payload = frame[2:-2]
        self._last_size = (payload[0] >> 4) & 0x03
        sealed = self.chain.seal_poll(payload, now, deadline=self.master.deadline())
        # The master said what it sent: the frame that left is the sealed one.
        self._events.extend(dataclasses.replace(e, frame=sealed) if isinstance(e, PollSent) else e
                            for e in self.master.take_events())
        return sealed

    def take_events(self) -> list[object]:
        events, self._events = self._events, []
        return events + self.master.take_events()

    # -- receiving ---------------------------------------------------------

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
        got = self.chain.open_reply(contents, now)
        if got is None:
            self.stats2.inauthentic += 1
            return [InauthenticFrame("reply")]
        if got.late:
            self.stats2.late += 1
            return [LateReply(got.sync)]
        if self.on_reply is not None:
            self.on_reply(got.payload, got.sync, now)
        if not got.sync:
            return self.master.receive(got.payload, now)
        self._hello_deadline = None  # the HELLO is answered: the token is ours
        first = self.stats2.syncs == 0
        restarted = not first and got.boot != self._boot
        self._boot = got.boot
        self.stats2.syncs += 1
        self.stats2.restarts_seen += restarted
        events: list[object] = [Synced(got.boot, restarted, first)]
        events.extend(self.master.on_sync(got.payload, restarted, now, now - got.sent_at))
        return events


def _check_max_frame(max_frame: int) -> None:
    if max_frame < SYNC_FRAME_BYTES:
        raise ValueError(f"version 2 needs a maximum frame size of at least {SYNC_FRAME_BYTES} bytes "
                         f"(a SYNC reply), got {max_frame}")
