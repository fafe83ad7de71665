"""`INTERFACE:CHANNEL` names of CAN buses, as the command line takes them."""

from __future__ import annotations

from sisa.core.errors import ConfigError


def parse_can_spec(text: str) -> tuple[str, str]:
    """('slcan', '/dev/pts/3') from 'slcan:/dev/pts/3'; any python-can interface works, except
    udp_multicast, which cannot be held to the loopback interface, and socketcand, which needs
    a host and port."""
    interface, sep, channel = text.partition(":")
    if not sep or not interface or not channel:
        raise ConfigError(f"CAN bus {text!r}: use INTERFACE:CHANNEL, e.g. slcan:/dev/pts/3, "
                          "virtual:sisa or socketcan:can0")
    if interface == "udp_multicast":
        raise ConfigError("CAN interface udp_multicast cannot be held to loopback; use slcan")
    if interface == "socketcand":  # python-can raised a TypeError for the missing host and port
        raise ConfigError(f"CAN bus {text!r}: socketcand needs a daemon's host and port, which "
                          "INTERFACE:CHANNEL cannot give (and a network link is not held to "
                          "loopback); use slcan")
    return interface, channel
