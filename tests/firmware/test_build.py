"""`make firmware` builds the sketch for the UNO and it fits: flash (text + data) within the 32,256 bytes
the bootloader leaves, static RAM (data + bss) within 1,536 of the 2,048 bytes, the rest for the stack."""

import re
import subprocess

FLASH_MAX, RAM_MAX = 32_256, 1_536


def test_the_firmware_fits_the_uno_and_make_says_how_much_it_uses(firmware):
    elf, report = firmware
    sections = dict(re.findall(r"^(\.\w+)\s+(\d+)", subprocess.run(["avr-size", "-A", str(elf)], check=True,
                                                                   capture_output=True, text=True).stdout, re.M))
    flash = int(sections[".text"]) + int(sections.get(".data", 0))
    ram = int(sections.get(".data", 0)) + int(sections.get(".bss", 0))
    assert 1000 < flash <= FLASH_MAX and 0 < ram <= RAM_MAX
    assert f"flash {flash} of {FLASH_MAX} bytes, static RAM {ram} of {RAM_MAX} bytes" in report


def test_the_hex_to_flash_is_built_beside_the_elf(firmware):
    elf, _ = firmware
    lines = elf.with_suffix(".hex").read_text().splitlines()
    assert lines[0].startswith(":") and lines[-1] == ":00000001FF"        # Intel HEX, with its end record
