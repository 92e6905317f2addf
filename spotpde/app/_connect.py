"""Connecting a sweep to a user's Dask scheduler: the address is checked, it must answer
within :func:`connect_timeout` seconds and must not speak first (a service that sends a
banner is not a Dask scheduler). Public through :mod:`spotpde.app.sweep`.
"""

from __future__ import annotations

import asyncio
import math
import os
import socket
import threading

from ..errors import CaseError

#: Seconds allowed to connect to a user's scheduler, unless ``$SPOTPDE_CONNECT_TIMEOUT``
#: says otherwise (read when connecting: :func:`connect_timeout`), and its largest value.
CONNECT_TIMEOUT = 10.0
MAX_CONNECT_TIMEOUT = 3600.0


def connect_timeout() -> float:
    """Seconds to connect to a scheduler: ``$SPOTPDE_CONNECT_TIMEOUT`` if set, else
    :data:`CONNECT_TIMEOUT`.

    Raises:
        spotpde.CaseError: the variable is not a number of seconds in
            ``(0, MAX_CONNECT_TIMEOUT]`` (one line naming it).
    """
    text = os.environ.get("SPOTPDE_CONNECT_TIMEOUT", "").strip()
    if not text:
        return CONNECT_TIMEOUT
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 < value <= MAX_CONNECT_TIMEOUT:
        shown = text if len(text) <= 40 else text[:40] + "..."
        raise CaseError(f"SPOTPDE_CONNECT_TIMEOUT: must be a number of seconds in (0, "
                        f"{MAX_CONNECT_TIMEOUT:g}], got {shown!r}")
    return value


def _handshake(address: str, timeout: float) -> None:
    """Open and close one Dask comm to ``address`` (the protocol's handshake), in a
    thread with its own event loop, within ``timeout`` seconds.

    Raises:
        TimeoutError: no handshake within ``timeout`` (a port that accepts and is silent).
        OSError: the connection failed or was closed.
    """
    from distributed.comm import connect as comm_connect

    async def probe():
        comm = await asyncio.wait_for(comm_connect(address, timeout=timeout), timeout)
        await comm.close()

    outcome: list = []

    def target():
        try:
            asyncio.run(probe())
            outcome.append(None)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            outcome.append(exc)

    thread = threading.Thread(target=target, daemon=True)   # never delays the exit
    thread.start()
    thread.join(timeout + 1.0)
    if not outcome:
        raise TimeoutError(f"no handshake within {timeout:g} s")
    if outcome[0] is not None:
        raise outcome[0]


def connect(address: str, timeout: float | None = None):
    """A ``distributed.Client`` on a running scheduler, checked first.

    Args:
        address: ``tcp://host:port``, ``tls://host:port`` or ``host:port``.
        timeout: seconds to connect, in ``(0, MAX_CONNECT_TIMEOUT]`` (default
            :func:`connect_timeout`).

    Raises:
        ValueError: ``timeout`` out of range.
        spotpde.CaseError: ``--scheduler: ...`` for a malformed address, nothing
            listening, no answer within ``timeout``, a service that is not a Dask
            scheduler (it sends a banner before being asked), or a failed handshake.
    """
    from distributed import Client

    if timeout is None:
        timeout = connect_timeout()
    elif not (isinstance(timeout, (int, float)) and 0 < timeout <= MAX_CONNECT_TIMEOUT):
        raise ValueError(f"timeout: must be a number of seconds in (0, "
                         f"{MAX_CONNECT_TIMEOUT:g}], got {timeout!r}")
    timeout = float(timeout)
    scheme, sep, rest = address.strip().rpartition("://")
    host, colon, port = rest.rpartition(":")
    host = host.strip("[]")
    if (sep and scheme not in ("tcp", "tls")) or not colon or not host or not port.isdigit() \
            or not 0 < int(port) < 65536 or any(c.isspace() for c in host):
        raise CaseError(f"--scheduler: not a Dask scheduler address; expected "
                        f"tcp://host:port or host:port, got {address!r}")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout) as sock:
            sock.settimeout(min(0.5, timeout))
            try:
                banner = sock.recv(64)
            except TimeoutError:          # silent until asked: as a Dask scheduler is
                banner = None
    except TimeoutError:
        raise CaseError(f"--scheduler: {address} did not answer within {timeout:g} s") from None
    except OSError as exc:
        raise CaseError(f"--scheduler: cannot connect to {address} "
                        f"({exc.strerror or exc})") from None
    if banner is not None:
        shown = banner.split(b"\n")[0].decode("ascii", "replace").strip()[:40]
        raise CaseError(f"--scheduler: {address} is not a Dask scheduler (it sent "
                        f"{shown!r} before being asked)" if banner else
                        f"--scheduler: {address} closed the connection; not a Dask scheduler")
    full = f"{scheme or 'tcp'}://{rest}"
    try:
        _handshake(full, timeout)   # Client's own timeout does not bound the handshake
        return Client(full, timeout=timeout)
    except TimeoutError:
        raise CaseError(f"--scheduler: no Dask scheduler at {address} (no answer to the "
                        f"handshake within {timeout:g} s)") from None
    except (OSError, ValueError, MemoryError, OverflowError) as exc:
        raise CaseError(f"--scheduler: no Dask scheduler at {address} "
                        f"({type(exc).__name__}: {str(exc)[:200]})") from None
