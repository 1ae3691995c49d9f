"""``pdr record --list``: the serial ports pyserial finds, with their USB description."""

from __future__ import annotations


def list_ports() -> list[str]:
    """One line per port: device, description, and USB vendor:product and serial number when known."""
    from serial.tools import list_ports as lp

    lines = []
    for p in sorted(lp.comports(), key=lambda p: p.device):
        usb = f"  [USB {p.vid:04x}:{p.pid:04x}" + (f" serial {p.serial_number}" if p.serial_number else "") + "]" \
            if p.vid is not None else ""
        desc = p.description if p.description and p.description != "n/a" else "no description"
        maker = f" ({p.manufacturer})" if p.manufacturer else ""
        lines.append(f"{p.device}  {desc}{maker}{usb}")
    return lines
