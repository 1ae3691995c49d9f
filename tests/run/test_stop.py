"""Stopping ``pdr run`` from outside: a stop is the stop, whatever exception it surfaced as."""

import os
import signal
import time

import pytest

from pipeline.run.stop import Stopped, nothing_left_to_stop, stop_signals, stopped_by, stops_deferred


def _signalled(sig: int) -> BaseException:
    """What a C extension's initialisation makes of a signal's exception raised inside it: an ImportError."""
    try:
        try:
            os.kill(os.getpid(), sig)
            time.sleep(5)                                   # the handler raises before this ends
        except Stopped:
            raise ImportError("initialization failed")      # noqa: B904 (as the extension reports it)
    except ImportError as err:
        return err
    raise AssertionError("the signal raised nothing")


@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_stop_that_surfaced_as_another_exception_is_still_the_stop(sig, status):
    with stop_signals():
        err = _signalled(sig)
        stop = stopped_by(err)
    assert isinstance(err, ImportError) and stop is not None and stop.exit_status == status


def test_a_failure_of_its_own_is_not_a_stop():
    with stop_signals():
        assert stopped_by(ValueError("a bug")) is None
        assert stopped_by(KeyboardInterrupt()).exit_status == 130
    with stop_signals():
        _signalled(signal.SIGTERM)
    with stop_signals():                                    # a stop is forgotten with the block it ended
        assert stopped_by(ImportError("initialization failed")) is None


@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_stop_during_a_deferred_block_is_raised_at_its_end_and_not_inside(sig, status):
    reached_end = False
    with stop_signals(), pytest.raises(Stopped) as raised:
        with stops_deferred():
            os.kill(os.getpid(), sig)
            time.sleep(0.2)                                 # the handler has run by now, and raised nothing
            reached_end = True
    assert reached_end and raised.value.exit_status == status


def test_once_nothing_is_left_to_stop_a_stop_is_ignored_to_the_end():
    previous = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        with stop_signals():
            nothing_left_to_stop()
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN         # also after the block
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])
