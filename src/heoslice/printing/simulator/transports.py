"""Byte transports of the simulated controller: a pseudo-terminal, a TCP server, an in-process pipe.

The pipe's host end (:class:`PipePort`) has the subset of pyserial's ``Serial`` API the host uses;
:class:`SimConnector` hands a test's own :class:`~heoslice.printing.simulator.controller.SimController`
to the host as a connector, reconnectable like a real port.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import threading
import time


class Transport:
    """Bytes in and out of the controller: ``recv`` returns b'' on timeout, ``send`` may drop when nobody listens."""

    def recv(self, timeout: float) -> bytes:
        raise NotImplementedError

    def send(self, data: bytes) -> None:
        raise NotImplementedError

    def disconnect(self, seconds: float) -> None:
        """Model a pulled cable for ``seconds``."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the transport."""


class FdTransport(Transport):
    """The master side of a pseudo-terminal; a disconnect is modelled as ``seconds`` of silence."""

    def __init__(self, fd: int):
        self.fd = fd
        os.set_blocking(fd, False)
        self._mute_until = 0.0

    def recv(self, timeout: float) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], max(timeout, 0.0))
        if not ready:
            return b""
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return b""
        except OSError as err:
            if err.errno == errno.EIO:  # no process has the terminal side open right now
                time.sleep(min(timeout, 0.01))
                return b""
            raise
        return b"" if time.monotonic() < self._mute_until else data

    def send(self, data: bytes) -> None:
        if time.monotonic() < self._mute_until:
            return
        try:
            os.write(self.fd, data)
        except (BlockingIOError, OSError):
            pass  # terminal buffer full or closed: bytes are lost, as on a real UART

    def disconnect(self, seconds: float) -> None:
        self._mute_until = time.monotonic() + seconds

    def close(self) -> None:
        try:
            os.close(self.fd)
        except OSError:
            pass


class TcpServerTransport(Transport):
    """A TCP listener (``socket://host:port`` for the host); one connection at a time, re-accepted after a drop."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self._server = socket.create_server((host, port))
        self._server.setblocking(False)
        self.address = self._server.getsockname()[:2]
        self._conn: socket.socket | None = None
        self._down_until = 0.0

    def recv(self, timeout: float) -> bytes:
        if self._conn is None:
            if time.monotonic() >= self._down_until:
                ready, _, _ = select.select([self._server], [], [], max(timeout, 0.0))
                if ready:
                    try:
                        self._conn, _ = self._server.accept()
                        self._conn.setblocking(False)
                        self._conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    except OSError:
                        self._conn = None
            else:
                time.sleep(min(timeout, 0.01))
            return b""
        ready, _, _ = select.select([self._conn], [], [], max(timeout, 0.0))
        if not ready:
            return b""
        try:
            data = self._conn.recv(65536)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop()
        return data

    def send(self, data: bytes) -> None:
        if self._conn is None:
            return
        try:
            self._conn.sendall(data)
        except OSError:
            self._drop()

    def _drop(self) -> None:
        """Close the current client connection."""
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def disconnect(self, seconds: float) -> None:
        self._drop()
        self._down_until = time.monotonic() + seconds

    def close(self) -> None:
        self._drop()
        self._server.close()


class _ByteQueue:
    """One direction of an in-process pipe: bytes with a condition variable and a closed flag."""

    def __init__(self):
        self._data = bytearray()
        self._cond = threading.Condition()
        self.closed = False

    def put(self, data: bytes) -> None:
        """Append bytes and wake a reader."""
        with self._cond:
            if not self.closed:
                self._data += data
                self._cond.notify_all()

    def get(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes, waiting at most ``timeout`` s for the first."""
        with self._cond:
            if not self._data and not self.closed:
                self._cond.wait(timeout)
            out = bytes(self._data[:size])
            del self._data[:size]
            return out

    def waiting(self) -> int:
        """Bytes queued."""
        with self._cond:
            return len(self._data)

    def clear(self) -> None:
        """Drop queued bytes."""
        with self._cond:
            self._data.clear()

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()


class PipePort:
    """The host end of an in-process pipe, with the subset of the pyserial ``Serial`` API the printer uses."""

    def __init__(self, incoming: _ByteQueue, outgoing: _ByteQueue, name: str = "sim://"):
        self._in, self._out = incoming, outgoing
        self.timeout: float | None = 0.0
        self.port = name
        self.is_open = True

    def _check(self) -> None:
        """Raise SerialException when the pipe is closed, as pyserial does for a lost device."""
        import serial

        if not self.is_open or self._in.closed or self._out.closed:
            raise serial.SerialException(f"{self.port}: connection closed")

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read."""
        self._check()
        return self._in.waiting()

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes within ``timeout`` (b'' on timeout)."""
        self._check()
        data = self._in.get(size, self.timeout)
        if not data:
            self._check()
        return data

    def write(self, data: bytes) -> int:
        """Queue bytes for the controller."""
        self._check()
        self._out.put(bytes(data))
        return len(data)

    def flush(self) -> None:
        """Nothing is buffered on this side."""

    def reset_input_buffer(self) -> None:
        """Drop unread bytes."""
        self._in.clear()

    def close(self) -> None:
        self.is_open = False
        self._in.close()
        self._out.close()


class PipeTransport(Transport):
    """The controller end of an in-process pipe; a disconnect closes the pipe (the host sees an error)."""

    def __init__(self, incoming: _ByteQueue, outgoing: _ByteQueue):
        self._in, self._out = incoming, outgoing

    def recv(self, timeout: float) -> bytes:
        if self._in.closed:
            time.sleep(min(timeout, 0.01))
            return b""
        return self._in.get(65536, max(timeout, 0.0))

    def send(self, data: bytes) -> None:
        self._out.put(data)

    def disconnect(self, seconds: float) -> None:
        self._in.close()
        self._out.close()

    def close(self) -> None:
        self.disconnect(0.0)


def pipe_pair(name: str = "sim://") -> tuple[PipePort, PipeTransport]:
    """A connected (host port, controller transport) pair."""
    host_to_ctrl, ctrl_to_host = _ByteQueue(), _ByteQueue()
    return PipePort(ctrl_to_host, host_to_ctrl, name), PipeTransport(host_to_ctrl, ctrl_to_host)



class SimConnector:
    """A connector for a controller object the caller holds (tests, benchmarks): each open is a fresh pipe.

    The controller keeps running between opens, as a powered printer does; :meth:`close` stops it.
    """

    def __init__(self, controller, name: str = "sim://"):
        self.controller, self.name = controller, name
        self.baud = controller.config.baud / max(controller.config.time_scale, 1e-12)
        self._started = False

    def open(self) -> PipePort:
        """A fresh open port to the controller."""
        port, transport = pipe_pair(self.name)
        port.timeout = 0.005
        self.controller.attach(transport)
        if not self._started:
            self.controller.start()
            self._started = True
        return port

    def close(self) -> None:
        """Stop the controller."""
        if self._started:
            self.controller.stop()
            self._started = False
