"""Where the browser viewer listens: the ``--host`` and ``--port`` of ``pcdof view --serve``, checked first.

Checked before the frame is loaded and the server started, so that a mistyped address or a port that
another program holds is one line and an exit status (6, 12), not a library's traceback after the
work. The libraries that serve the page log a malformed request or a dropped browser tab with a
traceback; :func:`quiet_server_logs` turns those into nothing (or one line with ``-v``, everything with
``-vv``).
"""

from __future__ import annotations

import errno
import logging
import socket

from ...errors import InputError, ServeError, one_line

#: loggers of the libraries behind the page (aiohttp, asyncio's loop, wslink, trame)
SERVER_LOGGERS = ("aiohttp", "asyncio", "wslink", "trame", "trame_server", "trame_client")
#: ports tried when suggesting another one
_SUGGEST_SPAN = 50


def _addresses(host: str, port: int) -> list:
    try:
        return socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, ValueError) as err:
        why = getattr(err, "strerror", None) or err
        raise InputError(f"--host {one_line(host)!r} is not an address or a host name that resolves ({why}); "
                         "e.g. 127.0.0.1 (this machine only), ::1 or 0.0.0.0 (every interface)") from None


def _bind(info) -> None:
    """Bind a socket to one resolved address as the server will (an address family this machine lacks,
    such as IPv6 in some containers, is skipped, as asyncio skips it)."""
    family, kind, proto, _, address = info
    try:
        sock = socket.socket(family, kind, proto)
    except OSError:
        return
    with sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does
        sock.bind(address)


def free_port_near(host: str, port: int) -> int | None:
    """A port after *port* that *host* can listen on now, or None."""
    for candidate in range(port + 1, min(port + _SUGGEST_SPAN, 65535) + 1):
        try:
            for info in _addresses(host, candidate):
                _bind(info)
        except (OSError, InputError):
            continue
        return candidate
    return None


def check_listen_address(host: str, port: int) -> None:
    """Fail unless the server can listen on *host* at *port* now.

    Parameters
    ----------
    host : str, an IP address or a host name of this machine
    port : int, 1..65535

    Raises
    ------
    InputError
        *host* is not an address, does not resolve, or is not an address of this machine.
    ServeError
        The port is in use (the message suggests a free one) or needs privileges.
    """
    if not isinstance(host, str) or not host or "\x00" in host:
        raise InputError(f"--host must be an address or a host name; got {host!r}")
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise InputError(f"--port must be an integer in 1..65535; got {port!r}")
    for info in _addresses(host, port):
        try:
            _bind(info)
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                other = free_port_near(host, port)
                hint = f"e.g. --port {other}" if other else "with --port"
                raise ServeError(f"port {port} on {one_line(host)} is already in use (another pcdof view --serve, "
                                 f"or another server?); choose another port, {hint}") from None
            if err.errno == errno.EADDRNOTAVAIL:
                raise InputError(f"--host {one_line(host)!r} is not an address of this machine; e.g. 127.0.0.1 "
                                 "or 0.0.0.0") from None
            if err.errno == errno.EACCES:
                raise ServeError(f"cannot listen on port {port}: permission denied (ports below 1024 need "
                                 "privileges); choose --port 1024 or above") from None
            raise ServeError(f"cannot listen on {one_line(host)} port {port}: {err.strerror or err}") from None


class _QuietServerRecords(logging.Filter):
    """Records of :data:`SERVER_LOGGERS`: dropped, or one line without traceback with ``-v``, kept with ``-vv``."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.name.split(".")[0] in SERVER_LOGGERS:
            return True
        root = logging.getLogger()
        if root.isEnabledFor(logging.DEBUG):
            return True
        if not root.isEnabledFor(logging.INFO):
            return False
        text = record.getMessage()
        if record.exc_info and record.exc_info[1] is not None:
            text += f": {type(record.exc_info[1]).__name__}: {record.exc_info[1]}"
        record.msg, record.args = one_line(text), ()
        record.exc_info = record.exc_text = record.stack_info = None
        return True


_FILTER = _QuietServerRecords()


def quiet_server_logs() -> None:
    """Keep the serving libraries' tracebacks (a malformed request, a dropped tab) off the terminal.

    Installed on the named loggers (records logged to them directly, even without a handler of
    pcdof's) and on the root logger's handlers (records of their child loggers); idempotent.
    """
    for name in SERVER_LOGGERS + ("aiohttp.server", "aiohttp.access", "aiohttp.web", "aiohttp.websocket"):
        logger = logging.getLogger(name)
        if _FILTER not in logger.filters:
            logger.addFilter(_FILTER)
    for handler in logging.getLogger().handlers:
        if _FILTER not in handler.filters:
            handler.addFilter(_FILTER)
