"""Building what the firmware tests run: the sketch for the ATmega328P (``make firmware``, which installs
Debian's packages as root and otherwise names the missing ones) and the controller's header for the host.

A machine without the toolchain fails these tests with one line that says what to do, rather than asking
for a password; ``PDR_NO_FIRMWARE=1`` leaves the AVR tests out (tests/firmware/conftest.py)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SKETCH_DIR = REPO / "firmware" / "pdr_logger"
WHAT_TO_DO = "run `make firmware-deps` as root, or set PDR_NO_FIRMWARE=1 to leave the firmware tests out"


def build_firmware(build_dir: Path) -> tuple[Path, str]:
    """``make firmware`` into ``build_dir``: (the .elf, make's size report)."""
    done = subprocess.run(["make", "-s", "--no-print-directory", "firmware", f"FIRMWARE_BUILD={build_dir}"],
                          cwd=REPO, capture_output=True, text=True)
    if done.returncode != 0:
        pytest.fail(f"make firmware failed: {first_reason(done.stderr)} ({WHAT_TO_DO})", pytrace=False)
    return build_dir / "pdr_logger.elf", done.stdout


def first_reason(stderr: str) -> str:
    """The line that says why make failed: the first that is not make's own "make: *** ... Error" trailer."""
    lines = [line for line in stderr.strip().splitlines() if line.strip()]
    said = [line for line in lines if not line.startswith(("make:", "make["))]
    return (said or lines or ["no output"])[0]


def build_host_driver(build_dir: Path) -> Path:
    """decide_driver.c with the sketch's header, compiled by the host's gcc as a shared library."""
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.fail(f"the host test of the controller needs gcc: {WHAT_TO_DO}", pytrace=False)
    lib = build_dir / "libpdr_decide.so"
    subprocess.run([gcc, "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC", f"-I{SKETCH_DIR}",
                    str(Path(__file__).with_name("decide_driver.c")), "-o", str(lib)], check=True)
    return lib


def build_cosim(build_dir: Path) -> Path:
    """cosim.c (the firmware in libsimavr, its pins wired to the test's plant), compiled by the host's gcc."""
    gcc = shutil.which("gcc")
    if gcc is None or not Path("/usr/include/simavr/sim_avr.h").exists():
        pytest.fail(f"the closed-loop test needs gcc and libsimavr-dev: {WHAT_TO_DO}", pytrace=False)
    exe = build_dir / "cosim"
    subprocess.run([gcc, "-O2", "-Wall", "-Wextra", "-Werror", "-I/usr/include/simavr",
                    str(Path(__file__).with_name("cosim.c")), "-o", str(exe), "-lsimavr"], check=True)
    return exe
