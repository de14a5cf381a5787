"""Where ``nue view`` listens: one interface (the loopback, 127.0.0.1, unless ``--host`` says otherwise), its
two ports checked on that interface before anything starts, and the page server bound to it.

The data stream is Rerun's gRPC server, a sink of the recording bound with ``bind_ip``. The page is Rerun's web
viewer served by the ``rerun`` program that ships in the ``rerun-sdk`` wheel (``rerun --serve-web --bind HOST``),
because the SDK's in-process page server always listens on every interface. That process ends with the viewer,
and with nue however nue ends (on Linux through the parent-death signal; elsewhere at interpreter exit).
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import ipaddress
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import quote

from nue.errors import ConfigError

LOOPBACK = "127.0.0.1"
"""The default interface: only this machine reaches the page and the data."""
EVERY_INTERFACE = ("0.0.0.0", "::")
"""Hosts that listen on every interface of the machine."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is reachable from this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def check_port(port: int, option: str, host: str = LOOPBACK) -> None:
    """:class:`ConfigError` unless a server can listen on ``host:port``: ``error: <option>: port N is taken ...``,
    or ``error: --host: ...`` for a host that is not an address of this machine."""
    if not 0 < port < 65536:
        raise ConfigError(option, f"port {port} is outside 1..65535")
    with socket.socket(_family(host), socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except socket.gaierror:
            raise ConfigError("--host", f"{host!r} is not an address or name of this machine") from None
        except OSError as exc:
            if exc.errno == errno.EADDRNOTAVAIL:
                raise ConfigError("--host", f"{host} is not an address of this machine") from None
            raise ConfigError(option, f"port {port} is taken (another program listens there); choose another") from None


def url_host(host: str, local: bool = False) -> str:
    """The host part of an address on ``host``: the interface itself, or for every interface this machine's
    name (``local``: the loopback, for a browser on this machine)."""
    if host in EVERY_INTERFACE:
        host = LOOPBACK if local else socket.gethostname()
    return f"[{host}]" if ":" in host else host


def wait_port_closed(host: str, port: int, timeout: float = 10.0) -> bool:
    """Wait until nothing accepts connections on ``port`` of ``host`` (an interface; every interface is probed on the
    loopback), at most ``timeout`` seconds: a server that stops in the background (rerun's gRPC sink after
    ``disconnect``) has then let go of its port. Whether it did."""
    probe = LOOPBACK if host in EVERY_INTERFACE else host.strip("[]")
    end = time.monotonic() + timeout
    while True:
        with socket.socket(socket.AF_INET6 if ":" in probe else socket.AF_INET) as s:
            s.settimeout(1.0)
            if s.connect_ex((probe, port)) != 0:
                return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.05)


def grpc_url(host: str, grpc_port: int) -> str:
    """The data stream's address, as the page asks for it."""
    return f"rerun+http://{host}:{grpc_port}/proxy"


def page_url(host: str, port: int, grpc_port: int) -> str:
    """The page's address on ``host`` (as :func:`url_host` gives it), pointing the viewer at the data stream."""
    return f"http://{host}:{port}/?url={quote(grpc_url(host, grpc_port), safe='')}"


def rerun_program() -> Path:
    """The ``rerun`` program of the installed ``rerun-sdk`` (``RERUN_CLI_PATH`` overrides it, as for ``rerun``)."""
    if os.environ.get("RERUN_CLI_PATH"):
        return Path(os.environ["RERUN_CLI_PATH"])
    import rerun_cli

    path = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
    if not path.is_file():
        raise ConfigError("nue view", f"the rerun program is missing ({path}); reinstall: pip install 'nue[view]'")
    return path


def _parent_death_signal():
    """A function for the child between fork and exec that asks Linux to send it SIGTERM when its parent ends
    (``prctl(PR_SET_PDEATHSIG)``), resolved here so that the child imports and loads nothing; None elsewhere."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    prctl = ctypes.CDLL(None, use_errno=True).prctl
    return lambda: prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1


class PageServer:
    """Rerun's web viewer on ``host:port`` (a ``rerun`` process), whose page reads the data stream at ``data_url``;
    ready when constructed (:class:`ConfigError` if it does not come up within ``timeout`` seconds). Start it from
    the thread that lives as long as it should (Linux ties the process to the thread that started it)."""

    def __init__(self, host: str, port: int, data_url: str, timeout: float = 60.0):
        self.host, self.port = host, port
        self._log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [str(rerun_program()), "--serve-web", "--bind", host, "--web-viewer-port", str(port), data_url],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self._log,
            preexec_fn=_parent_death_signal())
        atexit.register(self.close)
        self._wait_ready(timeout)

    def _wait_ready(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        address = (url_host(self.host, local=True).strip("[]"), self.port)
        while True:
            with socket.socket(_family(address[0]), socket.SOCK_STREAM) as s:
                if s.connect_ex(address) == 0:
                    return
            exited = self.proc.poll() is not None
            if exited or time.monotonic() > deadline:
                why = ((self._last_log_line() or f"exit status {self.proc.returncode}") if exited
                       else f"not listening after {timeout:.0f} s")
                self.close()
                raise ConfigError("--port", f"the page server (rerun --serve-web) did not start: {why}")
            time.sleep(0.05)

    def _last_log_line(self) -> str:
        self._log.seek(0)
        text = re.sub(r"\x1b\[[0-9;]*m", "", self._log.read().decode(errors="replace"))  # no terminal colours
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        return lines[-1] if lines else ""

    def close(self) -> None:
        """Stop the page server (idempotent)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        with contextlib.suppress(Exception):
            self._log.close()
        atexit.unregister(self.close)
