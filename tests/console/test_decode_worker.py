"""The console's decode thread (DaemonWorker) and the operator's quiet moment
(`Operator.wait_debt_idle`): what the memory benchmark waits for before it
starts and stops tracemalloc (console/bench/console.py says why)."""

from __future__ import annotations

import threading

from rovlink.console.session.images import DaemonWorker
from rovlink.console.session.radio import Operator


def test_wait_idle_waits_for_the_call_in_hand_and_those_queued():
    worker = DaemonWorker("test-decode")
    release = threading.Event()
    ran = []
    worker.submit(lambda: release.wait(30))
    worker.submit(lambda: ran.append("second"))
    assert worker.wait_idle(0.2) is False          # the first call still holds the thread
    assert ran == []
    release.set()
    assert worker.wait_idle(30) is True
    assert ran == ["second"]                        # idle means every call submitted before has run
    worker.shutdown()
    assert worker.wait_idle(30) is True             # shut down: idle once its thread ended


def test_a_worker_shut_down_with_a_call_in_hand_is_not_idle_until_it_returns():
    worker = DaemonWorker("test-decode")
    release, started = threading.Event(), threading.Event()

    def call():
        started.set()
        release.wait(30)

    worker.submit(call)
    assert started.wait(30)
    worker.shutdown()
    assert worker.wait_idle(0.2) is False
    release.set()
    assert worker.wait_idle(30) is True


def test_the_operator_is_quiet_once_debts_warm_up_is_done():
    operator = Operator(None)
    try:
        assert operator.wait_debt_idle(300) is True
        assert not operator._warm_up.is_alive()
    finally:
        operator.close()
