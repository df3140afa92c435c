"""Every order's fate (console/session/fates.py's `Fate`): queued or requested,
sent, then acknowledged, followed, rejected (with the ROV's reason), cancelled
or unknown; refused only when the console itself would not send it.

One-shot orders (POSITION, IMAGE, STOP) are settled by the link's events,
which name them by the master's ids.  ARM/DISARM and MODE are requests: the
vehicle's reported state says whether it followed.  The link repeats a request
for a while (§2: 3 s from when it first goes out); after that it is
"waiting", with its age, and still watched, so that a vehicle that follows
late is shown to have followed (ArduSub may arm seconds after it was asked,
and at the link's start the request waits for the reference).  A request
stops being watched when the vehicle follows it, the ROV rejects it or a
newer request of its kind supersedes it.  Every change is recorded,
published ("order") and, when it went wrong, an alert in the log.
"""

from __future__ import annotations

import itertools
from typing import Any, Callable

from rovlink.link.vocabulary import REQUESTABLE_MODES

from .fates import Fate, fields, parse_recorded, words
from .odometry import Fix

ORDERS_KEPT = 200
# Each change of any order takes the next number, across the books a process makes (a
# replay seeking back makes a new one): a page keeps the copy with the highest.
_VERSIONS = itertools.count(1)
EARLY_KEPT = 64    # master ids not mapped yet whose news is kept for them
ORDERS_LISTED = 50

# The modes a pilot may request: the protocol's own list (1..6).
MODE_NAMES = {m.name: m for m in REQUESTABLE_MODES}
REPORTED_MODE_NAMES = {0: "UNKNOWN", **{int(m): m.name for m in MODE_NAMES.values()}, 7: "OTHER"}


class OrderBook:
    """The orders of a session; any thread (`lock` is the session's re-entrant lock)."""

    def __init__(self, *, lock, record: Callable[[dict], None], publish: Callable[[str, Any], None],
                 note: Callable[..., None]) -> None:
        self._lock, self._record, self._publish, self._note = lock, record, publish, note
        self._orders: dict[int, dict] = {}  # console order id -> its info (kind, state, times, details)
        self._next_id = 1
        self._by_master_id: dict[int, int] = {}  # the master's one-shot order ids -> ours
        # What the master said of ids not mapped yet: a link process's events may come
        # before its answer to the call that queued the order (`queued` applies them).
        self._early: dict[int, list[tuple]] = {}
        self._requests: dict[str, int] = {}  # "arm"/"mode" -> our id of the request awaiting its effect
        self._image_settings: dict[int, Any] = {}  # IMAGE orders -> the settings they carry
        self._when_settled: dict[int, Callable[[Fate, str], None]] = {}  # order id -> told its first fate past pending

    # -- new orders -------------------------------------------------------

    def new(self, kind: str, fate: Fate, detail: dict, t: float) -> int:
        """A console order id and its record."""
        assert isinstance(fate, Fate), fate
        with self._lock:
            order_id = self._next_id
            self._next_id += 1
            info = {"id": order_id, "kind": kind, **fields(fate), "t_queued": t, f"t_{fate.value}": t, **detail,
                    "version": next(_VERSIONS)}
            self._orders[order_id] = info
            if len(self._orders) > ORDERS_KEPT:
                for old in sorted(self._orders)[:-ORDERS_KEPT]:
                    del self._orders[old]
                    self._when_settled.pop(old, None)
            if len(self._by_master_id) > 2 * ORDERS_KEPT:
                for old in sorted(self._by_master_id)[:-ORDERS_KEPT]:
                    del self._by_master_id[old]
            info = dict(info)
        self._record({"k": "order", "t": round(t, 4), "id": order_id, "kind": kind, **detail})
        self._publish("order", info)
        return order_id

    def queued(self, order_id: int, master_id: int):
        """A one-shot order handed to the master under its id; what the master already
        said of that id applies now.  Returns what `settled` would have (the settings
        of an IMAGE order already acknowledged), else None."""
        with self._lock:
            self._by_master_id[master_id] = order_id
            early = self._early.pop(master_id, [])
        settings = None
        for what, args in early:
            if what == "sent":
                self.sent(order_id, *args)
            else:
                settings = self.settled(master_id, *args) or settings
        return settings

    def _said_early(self, master_id: int, what: str, args: tuple) -> None:
        # (lock held)
        self._early.setdefault(master_id, []).append((what, args))
        if len(self._early) > EARLY_KEPT:
            del self._early[min(self._early)]

    def image_order(self, order_id: int, settings) -> None:
        with self._lock:
            self._image_settings[order_id] = settings

    def request(self, what: str, kind: str, detail: dict, t: float) -> int:
        """An arm ("arm") or mode ("mode") request, superseding the one before."""
        order_id = self.new(kind, Fate.REQUESTED, detail, t)
        self.watch(what, order_id, t)
        return order_id

    # -- their fate -------------------------------------------------------

    def sent(self, order_id: int | None, t: float) -> None:
        with self._lock:
            info = self._orders.get(order_id) if order_id is not None else None
            if info is None or Fate(info["state"]) not in (Fate.QUEUED, Fate.REQUESTED):
                return
        self.set_state(order_id, Fate.SENT, t)

    def sent_by_master_id(self, master_id: int, t: float) -> None:
        with self._lock:
            mine = self._by_master_id.get(master_id)
            if mine is None:
                self._said_early(master_id, "sent", (t,))
                return
        self.sent(mine, t)

    def watch(self, what: str, order_id: int, t: float) -> None:
        """An arm ("arm") or mode ("mode") order sent as a one-shot order (the
        acoustic link's ORDER) is watched as a request: followed when the
        vehicle's reported state shows it, however late; it supersedes the one
        before."""
        old = self._requests.pop(what, None)
        old_fate = self.fate(old)
        if old_fate is not None and not old_fate.ended:
            self.set_state(old, Fate.CANCELLED, t, "superseded by a newer request")
        self._requests[what] = order_id

    def request_sent(self, what: str, t: float) -> None:
        self.sent(self._requests.get(what), t)

    def settled(self, master_id: int, fate: Fate, t: float, reason: str = ""):
        """A one-shot order's fate, from the master (its ids).  Returns the
        settings of an IMAGE order the ROV acknowledged (they apply from its next
        picture on), else None."""
        with self._lock:
            order_id = self._by_master_id.get(master_id)
            if order_id is None:
                self._said_early(master_id, "settled", (fate, t, reason))
                return None
        info = self.set_state(order_id, fate, t, reason)
        if info is not None and info["kind"] == "IMAGE":
            with self._lock:
                settings = self._image_settings.pop(order_id, None)
            if fate is Fate.ACKNOWLEDGED:
                return settings
        return None

    def when_settled(self, order_id: int, then: Callable[[Fate, str], None]) -> None:
        """`then(fate, reason)` once order `order_id` is no longer pending (at once if it is
        not), on the thread that settles it: a `then` that gives orders hands them to a thread
        of its own."""
        with self._lock:
            info = self._orders.get(order_id)
            if info is None:
                return
            fate = Fate(info["state"])
            if fate.pending:
                self._when_settled[order_id] = then
                return
        then(fate, info["reason"])

    def set_state(self, order_id: int, fate: Fate, t: float, reason: str = "") -> dict | None:
        assert isinstance(fate, Fate), fate
        with self._lock:
            info = self._orders.get(order_id)
            if info is None:
                return None
            info.update(fields(fate, reason))
            info["t_" + fate.value] = t
            info["version"] = next(_VERSIONS)
            info = dict(info)
            then = None if fate.pending else self._when_settled.pop(order_id, None)
        self._record({"k": "order_state", "t": round(t, 4), "id": order_id, "kind": info["kind"],
                      "state": fate.value, "reason": reason})
        self._publish("order", info)
        if fate.alert:
            self._note(f"{info['kind']} order {order_id} {words(fate, reason)}", "alert")
        if then is not None:
            then(fate, reason)
        return info

    def fate(self, order_id: int | None) -> Fate | None:
        with self._lock:
            info = self._orders.get(order_id) if order_id is not None else None
            return None if info is None else Fate(info["state"])

    def get(self, order_id: int) -> dict | None:
        with self._lock:
            info = self._orders.get(order_id)
            return None if info is None else dict(info)

    def update(self, order_id: int, **fields) -> None:
        """Details of an order that change without its state (a Go-to's distance left)."""
        with self._lock:
            info = self._orders.get(order_id)
            if info is None:
                return
            info.update(fields)
            info["version"] = next(_VERSIONS)
            info = dict(info)
        self._publish("order", info)

    def check_requests(self, fix: Fix | None, t: float) -> None:
        """Arm and mode requests the vehicle's reported state shows followed,
        however late; those the ROV rejected or that were superseded are no
        longer watched."""
        if not self._requests:
            return
        reply = None if fix is None else fix.report
        for what, order_id in list(self._requests.items()):
            with self._lock:
                info = self._orders.get(order_id)
                info = None if info is None else dict(info)
            fate = None if info is None else Fate(info["state"])
            if fate is None or (fate.ended and fate is not Fate.UNKNOWN):
                self._requests.pop(what, None)  # followed, rejected or cancelled: the vehicle said
                continue
            followed = reply is not None and fix.arrived_at >= info["t_queued"] and (
                reply.armed == info["armed"] if what == "arm" else int(reply.mode) == int(MODE_NAMES[info["mode"]]))
            if followed:
                self._requests.pop(what, None)
                late = fate in (Fate.WAITING, Fate.UNKNOWN)
                self.set_state(order_id, Fate.FOLLOWED, t,
                               f"{t - info['t_queued']:.1f} s after it was asked" if late else "")
                if late:
                    self._note(f"{info['kind']} order {order_id} followed after all, "
                               f"{t - info['t_queued']:.1f} s after it was asked")

    def request_unrepeated(self, what: str, t: float, why: str) -> None:
        """The link no longer repeats a request the vehicle has not followed yet:
        it waits, still watched (the vehicle may follow late; it has said nothing)."""
        order_id = self._requests.get(what)
        if order_id is None or self.fate(order_id) not in (Fate.REQUESTED, Fate.SENT):
            return
        info = self.set_state(order_id, Fate.WAITING, t, why)
        if info is not None:
            self._note(f"{info['kind']} order {order_id} not followed yet ({why}); still watched", "warn")

    def link_ended(self, t: float, reason: str) -> list[int]:
        """The master that held the one-shot orders and the requests is gone (the
        link process ended): those it had not settled are unknown, with `reason`,
        but STOPs, whose ids are returned to be sent again.  Its ids mean nothing
        to the next master.  Requests stay watched: the vehicle may have them."""
        with self._lock:
            open_ids = {mine for mine in self._by_master_id.values()
                        if mine in self._orders and Fate(self._orders[mine]["state"]) in (Fate.QUEUED, Fate.SENT)}
            self._by_master_id.clear()
            self._early.clear()  # the next master's ids are its own
            stops = sorted(i for i in open_ids if self._orders[i]["kind"] == "STOP")
            requests = [i for i in self._requests.values()
                        if i in self._orders and Fate(self._orders[i]["state"]).pending]
        for order_id in sorted(open_ids - set(stops)) + requests:
            self.set_state(order_id, Fate.UNKNOWN, t, reason)
        return stops

    # -- a replay ---------------------------------------------------------

    def replayed(self, record: dict, t: float) -> None:
        """A recorded order or change of its state, listed as it was."""
        order_id = record.get("id")
        if order_id is None:  # recordings older than order ids
            self._note("(replay) " + ", ".join(f"{k}={v}" for k, v in record.items() if k not in ("k", "t")))
            return
        with self._lock:
            if record["k"] == "order":
                detail = {k: v for k, v in record.items() if k not in ("k", "t", "id", "kind")}
                self._orders[order_id] = {"id": order_id, "kind": record.get("kind", "?"), **fields(Fate.QUEUED),
                                          "t_queued": t, **detail, "version": next(_VERSIONS)}
            elif order_id in self._orders:
                fate, reason = parse_recorded(str(record.get("state", "?")), record.get("reason"))
                self._orders[order_id].update(fields(fate, reason))
                self._orders[order_id]["t_" + fate.value] = t
                self._orders[order_id]["version"] = next(_VERSIONS)
            info = dict(self._orders[order_id]) if order_id in self._orders else None
        if info is not None:
            self._publish("order", info)

    # -- state ------------------------------------------------------------

    def state(self) -> list[dict]:
        with self._lock:
            return [dict(v) for _, v in sorted(self._orders.items())][-ORDERS_LISTED:]

    def last_master_id(self) -> int | None:
        """The master's id of the newest one-shot order (for tests and tools)."""
        with self._lock:
            return max(self._by_master_id) if self._by_master_id else None
