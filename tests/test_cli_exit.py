"""The ``pdr`` script leaves without the interpreter's teardown, yet does what an exit must: atexit
handlers, flushed output, the command's exit code; and with another thread alive it waits for it."""

import subprocess
import sys

PROBE = "import atexit, sys, threading, time\n{setup}\nsys.argv = ['pdr', *sys.argv[1:]]\n" \
        "from pipeline.cli import console\nconsole()\n"


def _console(setup: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", PROBE.format(setup=setup), *args], capture_output=True, text=True,
                          timeout=120)


def test_atexit_handlers_run_and_buffered_output_is_flushed():
    res = _console("atexit.register(lambda: print('atexit ran'))\nsys.stdout.write('x' * 100_000)", "--help")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("x" * 100_000)
    assert "Usage:" in res.stdout and res.stdout.rstrip().endswith("atexit ran")


def test_the_commands_exit_code_is_kept():
    res = _console("", "discover", "/nonexistent/nope.csv")
    assert res.returncode == 2 and res.stderr.startswith("pdr: error:")
    assert _console("", "no-such-command").returncode == 2


def test_another_thread_alive_is_waited_for():
    res = _console("threading.Thread(target=lambda: (time.sleep(0.5), print('thread done', flush=True))).start()",
                   "--help")
    assert res.returncode == 0 and "thread done" in res.stdout
