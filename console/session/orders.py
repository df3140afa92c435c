"""Every order's fate: queued or requested, sent, then acknowledged, followed,
rejected (with the ROV's reason), refused, cancelled or unknown.

One-shot orders (POSITION, IMAGE, STOP) are settled by the master's events,
which name them by the master's ids.  ARM/DISARM and MODE are requests the
link repeats; the vehicle's reported state says whether it followed, within
REQUEST_FOLLOW_S, else the request is refused.  Every change is recorded,
published ("order") and, when it went wrong, an alert in the log.
"""

from __future__ import annotations

from typing import Any, Callable

from rovlink.link.radio.messages import REQUESTABLE_MODES

from .odometry import Fix

REQUEST_FOLLOW_S = 3.0    # an arm/disarm/mode the vehicle does not follow in this time is refused
ORDERS_KEPT = 200
ORDERS_LISTED = 50

# The modes a pilot may request: the protocol's own list (1..6).
MODE_NAMES = {m.name: m for m in REQUESTABLE_MODES}
REPORTED_MODE_NAMES = {0: "UNKNOWN", **{int(m): m.name for m in MODE_NAMES.values()}, 7: "OTHER"}

# States that went wrong: the pilot is told loudly.
BAD_STATES = ("rejected", "refused", "not carried out", "unknown")


class OrderBook:
    """The orders of a session; any thread (`lock` is the session's re-entrant lock)."""

    def __init__(self, *, lock, record: Callable[[dict], None], publish: Callable[[str, Any], None],
                 note: Callable[..., None]) -> None:
        self._lock, self._record, self._publish, self._note = lock, record, publish, note
        self._orders: dict[int, dict] = {}  # console order id -> its info (kind, state, times, details)
        self._next_id = 1
        self._by_master_id: dict[int, int] = {}  # the master's one-shot order ids -> ours
        self._requests: dict[str, int] = {}  # "arm"/"mode" -> our id of the request awaiting its effect
        self._image_settings: dict[int, Any] = {}  # IMAGE orders -> the settings they carry

    # -- new orders -------------------------------------------------------

    def new(self, kind: str, state: str, detail: dict, t: float) -> int:
        """A console order id and its record."""
        with self._lock:
            order_id = self._next_id
            self._next_id += 1
            info = {"id": order_id, "kind": kind, "state": state, "t_queued": t, **detail}
            self._orders[order_id] = info
            if len(self._orders) > ORDERS_KEPT:
                for old in sorted(self._orders)[:-ORDERS_KEPT]:
                    del self._orders[old]
            if len(self._by_master_id) > 2 * ORDERS_KEPT:
                for old in sorted(self._by_master_id)[:-ORDERS_KEPT]:
                    del self._by_master_id[old]
            info = dict(info)
        self._record({"k": "order", "t": round(t, 4), "id": order_id, "kind": kind, **detail})
        self._publish("order", info)
        return order_id

    def queued(self, order_id: int, master_id: int) -> None:
        """A one-shot order handed to the master under its id."""
        with self._lock:
            self._by_master_id[master_id] = order_id

    def image_order(self, order_id: int, settings) -> None:
        with self._lock:
            self._image_settings[order_id] = settings

    def request(self, what: str, kind: str, detail: dict, t: float) -> int:
        """An arm ("arm") or mode ("mode") request, superseding the one before."""
        old = self._requests.pop(what, None)
        if old is not None:
            self.set_state(old, "cancelled: superseded by a newer request", t)
        order_id = self.new(kind, "requested", detail, t)
        self._requests[what] = order_id
        return order_id

    # -- their fate -------------------------------------------------------

    def sent(self, order_id: int | None, t: float) -> None:
        with self._lock:
            info = self._orders.get(order_id) if order_id is not None else None
            if info is None or info["state"] not in ("queued", "requested"):
                return
        self.set_state(order_id, "sent", t)

    def sent_by_master_id(self, master_id: int, t: float) -> None:
        with self._lock:
            mine = self._by_master_id.get(master_id)
        self.sent(mine, t)

    def request_sent(self, what: str, t: float) -> None:
        self.sent(self._requests.get(what), t)

    def settled(self, master_id: int, state: str, t: float):
        """A one-shot order's fate, from the master (its ids).  Returns the
        settings of an IMAGE order the ROV acknowledged (they apply from its next
        picture on), else None."""
        with self._lock:
            order_id = self._by_master_id.get(master_id)
        if order_id is None:
            return None
        info = self.set_state(order_id, state, t)
        if info is not None and info["kind"] == "IMAGE":
            with self._lock:
                settings = self._image_settings.pop(order_id, None)
            if state == "acknowledged":
                return settings
        return None

    def set_state(self, order_id: int, state: str, t: float) -> dict | None:
        with self._lock:
            info = self._orders.get(order_id)
            if info is None:
                return None
            info["state"] = state
            info["t_" + state.split(":")[0]] = t
            info = dict(info)
        self._record({"k": "order_state", "t": round(t, 4), "id": order_id, "kind": info["kind"], "state": state})
        self._publish("order", info)
        if state.startswith(BAD_STATES):
            self._note(f"{info['kind']} order {order_id} {state}", "alert")
        return info

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
            info = dict(info)
        self._publish("order", info)

    def check_requests(self, fix: Fix | None, t: float) -> None:
        """Arm and mode requests the vehicle followed, or did not in time."""
        if not self._requests:
            return
        reply = None if fix is None else fix.report
        for what, order_id in list(self._requests.items()):
            with self._lock:
                info = self._orders.get(order_id)
            if info is None:
                self._requests.pop(what, None)
                continue
            followed = reply is not None and fix.arrived_at >= info["t_queued"] and (
                reply.armed == info["armed"] if what == "arm" else int(reply.mode) == int(MODE_NAMES[info["mode"]]))
            if followed:
                self._requests.pop(what, None)
                self.set_state(order_id, "followed", t)
            elif t - info["t_queued"] > REQUEST_FOLLOW_S:
                self.refuse_request(what, t, f"the vehicle did not follow within {REQUEST_FOLLOW_S:g} s")

    def refuse_request(self, what: str, t: float, why: str) -> None:
        order_id = self._requests.pop(what, None)
        if order_id is None:
            self._note(f"{what} request {why}", "alert")
            return
        self.set_state(order_id, f"refused: {why}", t)

    def link_ended(self, t: float, state: str) -> list[int]:
        """The master that held the one-shot orders and the requests is gone (the
        link process ended): those it had not settled get `state`, but STOPs,
        whose ids are returned to be sent again.  Its ids mean nothing to the
        next master."""
        with self._lock:
            open_ids = {mine for mine in self._by_master_id.values()
                        if self._orders.get(mine, {}).get("state") in ("queued", "sent")}
            self._by_master_id.clear()
            stops = sorted(i for i in open_ids if self._orders[i]["kind"] == "STOP")
            requests = list(self._requests.values())
            self._requests.clear()
        for order_id in sorted(open_ids - set(stops)) + requests:
            self.set_state(order_id, state, t)
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
                self._orders[order_id] = {"id": order_id, "kind": record.get("kind", "?"), "state": "queued",
                                          "t_queued": t, **detail}
            elif order_id in self._orders:
                self._orders[order_id]["state"] = record.get("state", "?")
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
