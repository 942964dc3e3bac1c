"""Sockets of the simulator bridges: bound to one address, with an error that says what to do."""

from __future__ import annotations

import socket


def bind_socket(kind: int, host: str, port: int, instance: int) -> socket.socket:
    """A socket of `kind` (SOCK_STREAM listening, or SOCK_DGRAM) bound to host:port."""
    s = socket.socket(socket.AF_INET, kind)
    if kind == socket.SOCK_STREAM:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        s.bind((host, port))
        if kind == socket.SOCK_STREAM:
            s.listen(1)
    except OSError as e:
        s.close()
        proto = "TCP" if kind == socket.SOCK_STREAM else "UDP"
        raise OSError(
            f"cannot bind {proto} {host}:{port} ({e}); is another simulator on instance "
            f"{instance}? pick another --instance"
        ) from e
    return s
