"""PDR_NO_FIRMWARE=1 leaves out the tests that need the AVR toolchain and simavr (a machine where the
packages cannot be installed); without it, a missing toolchain fails them with what to do."""

import os
from pathlib import Path

import pytest

from tests.firmware.toolchain import build_firmware

NEED_AVR = ["test_build.py", "test_simavr.py", "test_closed_loop.py"]
collect_ignore = NEED_AVR if os.environ.get("PDR_NO_FIRMWARE") == "1" else []


@pytest.fixture(scope="session")
def firmware(tmp_path_factory) -> tuple[Path, str]:
    """The sketch built once per test process by `make firmware`: (the .elf, make's size report)."""
    return build_firmware(tmp_path_factory.mktemp("firmware"))
