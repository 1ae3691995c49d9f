"""The ``pdr`` script as a shell sees it: the command's exit code, a failure in one line on stderr,
everything printed reaching a pipe, and the interpreter's own exit (atexit handlers, other threads)."""

import subprocess
import sys
from pathlib import Path

PDR = Path(sys.executable).with_name("pdr")


def _pdr(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(PDR), *args], capture_output=True, text=True, timeout=120)


def test_help_is_printed_whole_and_exits_zero():
    res = _pdr("--help")
    assert res.returncode == 0, res.stderr
    assert "Usage:" in res.stdout and "discover" in res.stdout and res.stderr == ""


def test_the_commands_exit_code_is_kept_and_its_failure_is_one_line():
    res = _pdr("discover", "/nonexistent/nope.csv")
    assert res.returncode == 2 and res.stderr.startswith("pdr: error:")
    assert len(res.stderr.strip().splitlines()) == 1 and "nope.csv" in res.stderr
    assert _pdr("no-such-command").returncode == 2


def test_the_script_ends_as_the_interpreter_does_atexit_handlers_and_other_threads_included():
    """``pipeline.cli.main`` (the script's entry point) leaves through ``sys.exit``: a handler registered
    by a library runs, and a thread still working is waited for."""
    probe = ("import atexit, sys, threading, time\n"
             "atexit.register(lambda: print('atexit ran'))\n"
             "threading.Thread(target=lambda: (time.sleep(0.3), print('thread done', flush=True))).start()\n"
             "sys.stdout.write('x' * 100_000)\n"
             "sys.argv = ['pdr', '--help']\n"
             "from pipeline.cli import main\nmain()\n")
    res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("x" * 100_000) and "Usage:" in res.stdout
    assert "thread done" in res.stdout and res.stdout.rstrip().endswith("atexit ran")
