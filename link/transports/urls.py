"""Which transport a URL names (udp://, serial://, inproc://, wlmodem://), opened
as an `Endpoint`: the one place that knows them all, so that the transports
themselves import only their common base (no module imports one that imports
it back)."""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

from ..radio.frame import MAX_FRAME
from ..radio.messages import MIN_FRAME
from .transport import _INPROC, Endpoint, InprocEndpoint, TransportError, UdpEndpoint, _hostport, _SerialDriver
from .wlmodem import open_wlmodem


def open_transport(url: str) -> Endpoint:
    """Parse a transport URL; raises TransportError saying what is wrong."""
    parts = urlsplit(url)
    if parts.scheme == "wlmodem":  # it reads its own options (role, channel, baud, diag)
        return open_wlmodem(url)
    query = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
    common: dict = {}
    if "mtu" in query:
        mtu = query.pop("mtu")
        if not mtu.isdigit() or not MIN_FRAME <= int(mtu) <= MAX_FRAME:
            raise TransportError(f"mtu must be a frame size of {MIN_FRAME}..{MAX_FRAME} bytes (the smallest holds a "
                                 f"reply with one byte of picture), got {mtu!r}")
        common["max_frame"] = int(mtu)
    if "crlf" in query:
        common["crlf"] = query.pop("crlf") in ("1", "true", "yes")
    if parts.scheme == "udp":
        local = _hostport(parts.netloc, "udp:// address")
        if "peer" not in query:
            raise TransportError(
                f"udp:// needs ?peer=HOST:PORT (datagrams are taken only from the peer), got {url!r}"
            )
        peer = _hostport(query.pop("peer"), "peer")
        _no_extra(query, url)
        return UdpEndpoint(url, local, peer, **common)
    if parts.scheme == "serial":
        path = parts.path or parts.netloc
        if not path:
            raise TransportError(f"serial URL needs a device path, e.g. serial:///dev/ttyUSB0, got {url!r}")
        baud_text = query.pop("baud", "9600")
        if not baud_text.isdigit() or int(baud_text) <= 0:
            raise TransportError(f"baud must be a positive integer, got {baud_text!r}")
        _no_extra(query, url)
        return Endpoint(url, lambda ep: _SerialDriver(ep, path, int(baud_text)), **common)
    if parts.scheme == "inproc":
        name = parts.netloc or parts.path
        if not name:
            raise TransportError("inproc URL needs a name, e.g. inproc://link")
        _no_extra(query, url)
        ends = _INPROC.setdefault(name, [])
        if len(ends) >= 2:
            raise TransportError(f"inproc://{name} already has two ends")
        ep = InprocEndpoint(url, **common)
        if ends:
            ep.peer, ends[0].peer = ends[0], ep
        ends.append(ep)
        return ep
    raise TransportError(f"unknown transport {parts.scheme!r} in {url!r}: use udp://, serial://, wlmodem:// or inproc://")


def _no_extra(query: dict, url: str) -> None:
    if query:
        raise TransportError(f"unknown option(s) {', '.join(sorted(query))} in {url!r}")
