"""The browser viewer's server (``pcdof view --serve``) under hostile use.

* ``--host`` that is not an address of this machine, and a port another program holds, are one line
  and an exit status (6, 12) before the frame is loaded: no "anyone who can reach" warning first, no
  library traceback;
* malformed requests (a websocket request without its upgrade headers, a 200 KB header line, a bad
  request line, a request cut short) and a client that drops its connection print nothing: the
  server keeps serving and stops with exit status 0 on Ctrl-C;
* the serving libraries' log records lose their tracebacks: nothing at the default verbosity, one
  line with ``-v``, everything with ``-vv``.
"""

from __future__ import annotations

import base64
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time

import pytest

from conftest import one_line

from pcdof.errors import EXIT_CODES, InputError, ServeError

pytest.importorskip("trame")

INPUT, SERVE = EXIT_CODES[InputError], EXIT_CODES[ServeError]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve_args(frame: dict, port: int, *extra) -> list[str]:
    return ["view", str(frame["color"]), str(frame["depth"]), "--calib", str(frame["calib"]), "--serve",
            "--port", str(port), *extra]


def run(console_script, args, timeout=240) -> subprocess.CompletedProcess:
    return subprocess.run(console_script + args, capture_output=True, text=True, timeout=timeout)


# --------------------------------------------------------------------------- --host and --port
@pytest.mark.parametrize("host", ["not an address!", "256.1.1.1", "10.255.255.1", "1.2.3", "::g", "a" * 300])
def test_check_listen_address_refuses_a_host_that_is_not_this_machine(host):
    from pcdof.viewer.web.listen import check_listen_address

    with pytest.raises(InputError, match="--host"):
        check_listen_address(host, free_port())


@pytest.mark.parametrize("port", [0, 65536, -1, True, 80.0])
def test_check_listen_address_refuses_a_port_out_of_range(port):
    from pcdof.viewer.web.listen import check_listen_address

    with pytest.raises(InputError, match="--port"):
        check_listen_address("127.0.0.1", port)


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "0.0.0.0"])
def test_a_taken_port_is_named_and_another_suggested(host):
    from pcdof.viewer.web.listen import check_listen_address

    with socket.socket() as taken:
        taken.bind(("127.0.0.1" if host == "localhost" else host, 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ServeError, match=f"port {port} .* already in use") as info:
            check_listen_address(host, port)
        suggested = int(str(info.value).rsplit("--port ", 1)[1])
    assert suggested > port
    check_listen_address(host, suggested)  # the suggestion was free


@pytest.mark.parametrize("host", ["not an address!", "256.1.1.1"])
def test_view_serve_with_a_bad_host_is_one_line(small_frame, console_script, host):
    proc = run(console_script, serve_args(small_frame, free_port(), "--host", host))
    one_line(proc, INPUT, "--host")
    assert "anyone who can reach" not in proc.stderr


def test_view_serve_on_a_taken_port_is_one_line(small_frame, console_script):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = run(console_script, serve_args(small_frame, port))
    one_line(proc, SERVE, f"port {port}", "already in use", "--port")


# --------------------------------------------------------------------------- malformed requests, dropped clients
def _exchange(port: int, data: bytes, *, reset: bool = False) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        s.sendall(data)
        if reset:  # close with a TCP reset, as a crashed browser or a dropped network does
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            return b""
        out = b""
        try:
            while chunk := s.recv(65536):
                out += chunk
        except OSError:
            pass
        return out


def _ws_frame(obj) -> bytes:
    payload = json.dumps(obj).encode()
    mask = os.urandom(4)
    size = bytes([0x80 | len(payload)]) if len(payload) < 126 else bytes([0x80 | 126]) + struct.pack(">H", len(payload))
    return b"\x81" + size + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def _ws_client(port: int, messages, *, reset: bool) -> None:
    key = base64.b64encode(os.urandom(16))
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        s.sendall(b"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: "
                  + key + b"\r\nSec-WebSocket-Version: 13\r\n\r\n")
        assert s.recv(1024).startswith(b"HTTP/1.1 101")
        for message in messages:
            s.sendall(_ws_frame(message))
            time.sleep(0.3)
        if reset:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))


HELLO = {"wslink": "1.0", "id": "system:c0:0", "method": "wslink.hello", "args": [{"secret": "wslink-secret"}],
         "kwargs": {}}
GET_STATE = {"wslink": "1.0", "id": "rpc:c0:1", "method": "trame.state.get", "args": [], "kwargs": {}}


@pytest.mark.timeout(600)
def test_hostile_requests_and_dropped_clients_print_nothing(small_frame, console_script):
    port = free_port()
    proc = subprocess.Popen(console_script + serve_args(small_frame, port), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while True:
            assert proc.poll() is None, proc.stderr.read()
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "the server did not start listening"
                time.sleep(0.3)
        # answered (wslink answers a websocket request without its headers with an error status), not fatal
        assert _exchange(port, b"GET /ws HTTP/1.1\r\nHost: x\r\n\r\n").startswith(b"HTTP/1.1 ")
        assert _exchange(port, b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * 200_000 + b"\r\n\r\n")
        assert _exchange(port, b"NOT A REQUEST LINE\r\n\r\n")
        assert _exchange(port, b"GET / HTTP/1.1\r\n" + b"X-H: v\r\n" * 500 + b"\r\n")
        _exchange(port, b"GET / HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\nshort", reset=True)
        _ws_client(port, [HELLO], reset=True)  # a tab closed right after it connected
        _ws_client(port, [HELLO, GET_STATE], reset=True)  # a tab dropped while the server answers
        _ws_client(port, [HELLO, GET_STATE], reset=False)  # a tab closed cleanly
        page = _exchange(port, b"GET /index.html HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        assert page.startswith(b"HTTP/1.1 200"), page[:100]  # still serving
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert err.splitlines() == [f"pcdof: serving the viewer on http://127.0.0.1:{port}/ (Ctrl-C to stop)"], err


# --------------------------------------------------------------------------- the serving libraries' log records
LOG_SCRIPT = r"""
import logging, sys
from pcdof.cli._common import configure_logging
from pcdof.viewer.web.listen import quiet_server_logs
verbose = int(sys.argv[1])
configure_logging(verbose)
logging.getLogger().setLevel([logging.WARNING, logging.INFO, logging.DEBUG][verbose])
quiet_server_logs()
class ClientConnectionResetError(ConnectionResetError):
    pass
try:
    raise ClientConnectionResetError("Cannot write to closing transport")
except ConnectionResetError as err:
    logging.getLogger("asyncio").error("Task exception was never retrieved", exc_info=err)
    logging.getLogger("aiohttp.server").exception("Error handling request from 127.0.0.1")
    logging.getLogger("wslink.protocol").error("client gone", exc_info=err)
logging.getLogger("pcdof").warning("pcdof's own warning")
"""


@pytest.mark.parametrize("verbose,lines", [(0, 0), (1, 3), (2, None)])
def test_serving_libraries_log_no_traceback(verbose, lines):
    proc = subprocess.run([sys.executable, "-c", LOG_SCRIPT, str(verbose)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = proc.stderr.splitlines()
    assert out[-1] == "pcdof: pcdof's own warning"  # pcdof's own records are untouched
    library = out[:-1]
    if lines is None:  # -vv: everything, tracebacks included
        assert "Traceback" in proc.stderr
        return
    assert "Traceback" not in proc.stderr and len(library) == lines, proc.stderr
    assert all("ClientConnectionResetError" in line for line in library), library
