"""The station's log handler (`station.cli.log_handler`) under a Ctrl-C: wherever the interrupt
lands while the main thread logs a warning, another thread can log afterwards (a failing
heartbeat does, and the station then joins it)."""

import logging
import threading

from signal_places import ends, interrupted_at

import station.cli


def test_a_ctrl_c_while_the_main_thread_logs_leaves_the_log_usable():
    log = logging.Logger("station under test")  # not in logging's tree: pytest's handlers are not
    log.addHandler(station.cli.log_handler(verbose=False))
    code = (logging.__file__, threading.__file__, station.cli.__file__)
    k = 1
    while landed := interrupted_at(k, lambda: log.warning("aborted"), code):
        assert ends(lambda: log.warning("the heartbeat failed"), 10), (  # another thread's
            f"logging blocked after a Ctrl-C at {landed}")
        k += 1
    assert k > 20  # the sweep went through the handler's locking
