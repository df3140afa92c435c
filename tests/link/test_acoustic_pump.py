"""The one acoustic pump (link/acoustic/pump.py) every acoustic end runs: packets
split out of what the transport delivers, one packet in the modem at a time,
STOP first (the modem flushed and the packet handed at once)."""

from __future__ import annotations

from rovlink.link.acoustic.pump import AcousticPump


class Machine:
    def __init__(self) -> None:
        self.received: list[bytes] = []
        self.out: list[bytes] = []
        self.wants_flush = False

    def receive(self, packet: bytes, now: float) -> list:
        self.received.append(packet)
        return [("got", packet)]

    def tick(self, now: float) -> list:
        return []

    def next_packet(self, now: float) -> bytes | None:
        self.wants_flush = False
        return self.out.pop(0) if self.out else None


class PacedEndpoint:
    """A pty or socket to the emulator: no queue to read, so the pump paces."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.flushes = 0

    def send(self, packet: bytes) -> bool:
        self.sent.append(packet)
        return True

    def flush(self) -> None:
        self.flushes += 1


class QueueEndpoint(PacedEndpoint):
    """A Modem-M64 that tells its transmit queue."""

    def __init__(self) -> None:
        super().__init__()
        self.queued = 0

    def queue_length(self) -> int:
        return self.queued


def test_what_arrives_is_split_into_8_byte_packets_and_a_trailing_part_is_not_a_packet():
    machine, told = Machine(), []
    pump = AcousticPump(machine, PacedEndpoint(), clock=lambda: 0.0,
                        on_received=lambda packet, events, now: told.append(events))
    pump.split(bytes(range(20)), 1.0)
    assert machine.received == [bytes(range(8)), bytes(range(8, 16))]
    assert told == [[("got", bytes(range(8)))], [("got", bytes(range(8, 16)))]]


def test_packets_are_paced_on_a_plain_endpoint_and_a_flush_sends_at_once():
    machine, endpoint, now, sent = Machine(), PacedEndpoint(), [10.0], []
    pump = AcousticPump(machine, endpoint, clock=lambda: now[0], pace_s=1.0,
                        on_sent=lambda packet, t: sent.append((packet, t)))
    machine.out = [b"A" * 8, b"B" * 8, b"S" * 8]
    pump.turn()
    now[0] = 10.5
    pump.turn()  # within pace_s of the last: the modem may still hold it
    assert endpoint.sent == [b"A" * 8] and sent == [(b"A" * 8, 10.0)]
    now[0] = 11.0
    pump.turn()
    assert endpoint.sent[-1] == b"B" * 8
    machine.wants_flush = True  # a STOP: the modem flushed, the packet handed now, not after pace_s
    now[0] = 11.1
    pump.turn()
    assert endpoint.flushes == 1 and endpoint.sent[-1] == b"S" * 8 and not machine.wants_flush


def test_a_modem_that_tells_its_queue_gets_a_packet_only_when_it_is_empty():
    machine, endpoint = Machine(), QueueEndpoint()
    pump = AcousticPump(machine, endpoint, clock=lambda: 0.0)
    machine.out = [b"A" * 8, b"B" * 8]
    endpoint.queued = 1
    pump.turn()
    assert endpoint.sent == []
    endpoint.queued = 0
    pump.turn()
    assert endpoint.sent == [b"A" * 8]
