"""The client side of the Go1 low-level UDP link (legged_sdk 3.8; docs/reference.md#go1-low-level-link).

No handshake: the client sends a :class:`~amhe_cli.plants.go1.protocol.LowCmd`
from its local port (8080) to the robot (192.168.123.10:8007) and the robot
answers the sender with :class:`~amhe_cli.plants.go1.protocol.LowState`
packets. As the official wheel does, :meth:`LowLevelLink.recv` only accepts
packets from the robot's address and, of those waiting, keeps the newest.
"""

from __future__ import annotations

import select
import socket
import time

from amhe_cli.errors import AmheError
from amhe_cli.plants.go1.protocol import (HEADER, LOCAL_PORT, LOWSTATE_SIZE, ROBOT_ADDRESS, LowCmd, LowState,
                                          crc32_core)

#: Receive buffer per datagram: larger than any valid packet, so an oversized one is seen as such.
_RECV_BYTES = 2048
#: At most this many datagrams are read per :meth:`LowLevelLink.recv` call (a flood cannot stall the caller).
_MAX_DRAIN = 4096


class LinkError(AmheError):
    """The UDP link cannot be opened or used (bad address, port in use, network unreachable, closed link)."""


def parse_address(text: str, default_port: int) -> tuple[str, int]:
    """Parse ``"host:port"`` or ``"host"`` (IPv4 address or name) into ``(host, port)``.

    Args:
        text: e.g. ``"127.0.0.1:8007"`` or ``"192.168.123.10"``; surrounding spaces are ignored.
        default_port: the port when ``text`` names none.

    Returns:
        ``(host, port)`` with ``1 <= port <= 65535``; the host is not resolved.

    Raises:
        AmheError: empty host, a port that is not an integer in 1..65535, or an IPv6 form.
    """
    if not isinstance(text, str):
        raise AmheError(f"address must be a string like 127.0.0.1:8007, got {type(text).__name__}")
    s = text.strip()
    if s.count(":") > 1 or s.startswith("["):
        raise AmheError(f"address {text!r} looks like IPv6: expected an IPv4 host[:port] such as 127.0.0.1:8007")
    host, sep, port_text = s.partition(":")
    if not host or any(c.isspace() for c in host):
        raise AmheError(f"address {text!r} has no valid host: expected host[:port] such as 127.0.0.1:8007")
    if not sep:
        port = default_port
    elif port_text.isdigit():
        port = int(port_text)
    else:
        raise AmheError(f"address {text!r} has port {port_text!r}: expected an integer 1..65535")
    if not 1 <= int(port) <= 65535:
        raise AmheError(f"address {text!r} has port {port}: expected an integer 1..65535")
    return host, int(port)


def _resolve(host: str, port: int) -> tuple[str, int]:
    """``(host, port)`` with the host resolved to a dotted IPv4 address; LinkError if it cannot be."""
    try:
        return socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][:2]
    except (OSError, UnicodeError) as exc:
        raise LinkError(f"cannot resolve robot host {host!r}: {exc}") from None


class LowLevelLink:
    """A UDP socket bound to ``(bind_host, local_port)`` that talks to the robot (legged_sdk 3.8 low level).

    Args:
        robot: the robot's ``(host, port)``; :data:`~amhe_cli.plants.go1.protocol.ROBOT_ADDRESS` by default.
        local_port: the local UDP port (8080 as the SDK uses; 0 picks a free one).
        bind_host: local address to bind, ``"0.0.0.0"`` for all interfaces.

    Attributes:
        robot: the resolved robot address ``(ip, port)``; only packets from it are accepted.
        received: valid LowState packets received so far (newest or not).
        bad_packets: packets dropped (wrong length, header or CRC, or from another address).
        last_error: why the latest packet was dropped (or the latest receive error), else None.
        last_state_time: ``time.monotonic()`` [s] when the newest valid state was read, else None.

    Raises:
        LinkError (an AmheError): the robot host cannot be resolved, a port is out of range,
            or the local address cannot be bound (e.g. the port is in use).
    """

    def __init__(self, robot: tuple[str, int] = ROBOT_ADDRESS, local_port: int = LOCAL_PORT,
                 bind_host: str = "0.0.0.0"):
        try:
            host, port = robot
            port = int(port)
            local_port = int(local_port)
        except (TypeError, ValueError):
            raise LinkError(f"robot must be (host, port) and local_port an int, got {robot!r}, {local_port!r}") \
                from None
        if not 1 <= port <= 65535:
            raise LinkError(f"robot port {port} is out of range: expected 1..65535")
        if not 0 <= local_port <= 65535:
            raise LinkError(f"local port {local_port} is out of range: expected 0..65535 (0 picks a free port)")
        self.robot = _resolve(str(host), port)
        self.received = 0
        self.bad_packets = 0
        self.last_error: str | None = None
        self.last_state_time: float | None = None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((bind_host, local_port))
        except OSError as exc:
            self._sock.close()
            raise LinkError(f"cannot bind local UDP port {local_port} on {bind_host}: {exc.strerror or exc}") \
                from None
        self._sock.setblocking(False)

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound local ``(host, port)`` (the real port when 0 was asked for)."""
        return self._open().getsockname()[:2]

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called."""
        return self._sock is None

    def _open(self) -> socket.socket:
        if self._sock is None:
            raise LinkError("the robot link is closed")
        return self._sock

    def send(self, cmd: LowCmd) -> None:
        """Encode ``cmd`` and send it to the robot.

        Raises:
            ProtocolError: ``cmd`` holds a value the wire cannot carry (see :meth:`LowCmd.encode`).
            LinkError: the link is closed or the datagram cannot be sent (e.g. network unreachable).
        """
        sock = self._open()
        packet = cmd.encode()
        try:
            sent = sock.sendto(packet, self.robot)
        except BlockingIOError:
            raise LinkError(f"cannot send to robot {self.robot[0]}:{self.robot[1]}: socket send buffer full") \
                from None
        except OSError as exc:
            raise LinkError(f"cannot send to robot {self.robot[0]}:{self.robot[1]}: {exc.strerror or exc} "
                            f"(is this machine on the robot's network?)") from None
        if sent != len(packet):
            raise LinkError(f"sent {sent} of {len(packet)} bytes to robot {self.robot[0]}:{self.robot[1]}")

    def recv(self, timeout: float = 0.0) -> LowState | None:
        """Drain the socket and return the newest valid LowState, or None if none came.

        Waits up to ``timeout`` [s] for a valid state when none is waiting (0: do
        not wait). Invalid packets are counted in :attr:`bad_packets` with the
        reason in :attr:`last_error` and never returned; so are packets from any
        address but the robot's.

        Raises:
            AmheError: ``timeout`` negative or not a number.
            LinkError: the link is closed.
        """
        try:
            timeout = float(timeout)
        except (TypeError, ValueError):
            raise AmheError(f"recv timeout must be a number of seconds, got {timeout!r}") from None
        if not timeout >= 0:
            raise AmheError(f"recv timeout is {timeout}: expected seconds >= 0")
        sock = self._open()
        deadline = time.monotonic() + timeout
        while True:
            state = self._drain(sock)
            if state is not None:
                return state
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            select.select([sock], [], [], left)

    def _drain(self, sock: socket.socket) -> LowState | None:
        """Read every waiting datagram; count them; return the newest valid state (None if none)."""
        valid = []
        for _ in range(_MAX_DRAIN):
            try:
                data, source = sock.recvfrom(_RECV_BYTES)
            except BlockingIOError:
                break
            except OSError as exc:  # e.g. an ICMP error reported on the socket
                self.last_error = f"receive error: {exc.strerror or exc}"
                continue
            if source[:2] != self.robot:
                reason = (f"packet from {source[0]}:{source[1]}, expected the robot at "
                          f"{self.robot[0]}:{self.robot[1]}")
            elif len(data) != LOWSTATE_SIZE:
                reason = f"LowState packet is {len(data)} bytes, expected {LOWSTATE_SIZE}"
            elif data[:2] != HEADER:
                reason = f"LowState packet header is {data[:2].hex(' ')}, expected fe ef"
            elif int.from_bytes(data[-4:], "little") != crc32_core(data):
                reason = "LowState packet CRC mismatch (corrupted packet)"
            else:
                valid.append(data)
                continue
            self.bad_packets += 1
            self.last_error = reason
        if not valid:
            return None
        self.received += len(valid)
        self.last_state_time = time.monotonic()
        return LowState.decode(valid[-1])

    def close(self) -> None:
        """Close the socket (idempotent)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "LowLevelLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        sock = getattr(self, "_sock", None)
        if sock is not None:
            sock.close()
