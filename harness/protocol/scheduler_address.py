"""Whether ``--scheduler``'s address is a Dask scheduler's, asked before a run connects to it:
each mistake is one :class:`InputError` within seconds, naming what answers there where it can
tell (issue 35: the dashboard's port held a run for ever, another server's answer read as a
frame length asked for 3 EiB, a bad address was a traceback).

Dask reads the address (:func:`distributed.comm.get_address_host_port`) and asks the server
who it is (its ``identity`` call, over Dask's own rpc).  Two waits are bounded here by less
than Dask's: reaching the host (Dask retries a refused or unanswered connect for its whole
timeout) and the answer (Dask's connection handshake waits for ever on a server that says
nothing, such as the dashboard's web server reading the handshake as a request).  Only a server that has already
failed to answer as Dask is asked over HTTP whether it is a dashboard, whose
``/json/identity.json`` names its scheduler.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import json
import socket
import time
import urllib.error
import urllib.request

from iblbench.foundation.errors import InputError, argument

CONNECT_S = 3   # to reach the host: an unreachable one answers nothing
REFUSED_S = 5   # a closed port's retries
ANSWER_S = 2    # for a reached server to answer as Dask (a scheduler takes milliseconds)
SCHEDULER_PORT, DASHBOARD_PORT = 8786, 8787   # Dask's defaults
_TCP_SCHEMES = ("tcp", "tls", "ws", "wss")   # those reached by a TCP connect


def check_scheduler(address: str) -> None:
    """Return if a Dask scheduler answers at ``address``; otherwise raise an InputError that
    says why and, where it can tell, what was meant."""
    from distributed.comm.addressing import get_address_host_port, parse_address

    where = argument("scheduler", address)
    try:
        scheme = parse_address(address)[0]
        host, port = get_address_host_port(address)
    except ValueError as error:   # an unknown scheme, no port, a malformed host
        raise InputError(None, f"{where}: not a Dask scheduler address ({error}); "
                               f"{_web_address_hint(address)}") from None
    unreachable = _unreachable(host, port) if scheme in _TCP_SCHEMES else None
    if unreachable:
        raise InputError(None, f"{where}: no Dask scheduler answers there ({unreachable}); is "
                               "it running, and at this address?")
    identity = _identity(address)
    if identity is None:
        raise InputError(None, f"{where}: {_what_answers(host, port)}")
    if identity.get("type") != "Scheduler":
        scheduler = identity.get("scheduler")
        raise InputError(None, f"{where}: a Dask {identity.get('type', 'server')} answers there, "
                               "not a scheduler" + (f"; its scheduler is at {scheduler}"
                                                    if scheduler else ""))


def _unreachable(host: str, port: int) -> str | None:
    """Why ``host:port`` takes no TCP connection, None once it takes one.  A refused connection
    is tried again for REFUSED_S, as Dask does: a scheduler started beside the run may not
    listen yet."""
    deadline = time.monotonic() + REFUSED_S
    while True:
        try:
            socket.create_connection((host, port), timeout=CONNECT_S).close()
            return None
        except TimeoutError:
            return f"no answer in {CONNECT_S} s"
        except ConnectionRefusedError as error:
            if time.monotonic() >= deadline:
                return f"{error.strerror} for {REFUSED_S} s"
            time.sleep(0.1)
        except OSError as error:   # no such host, no route
            return error.strerror or str(error)


def _identity(address: str) -> dict | None:
    """The ``identity`` of the Dask server at ``address``, None if what answers is not Dask.
    Its own event loop on a thread of its own: the caller may be running one (a notebook)."""
    from distributed.core import rpc
    from distributed.security import Security

    security = Security().get_connection_args("client")   # TLS, as a Client would (the config's)

    async def ask():
        async with rpc(address, timeout=ANSWER_S, connection_args=security) as server:
            return await asyncio.wait_for(server.identity(), ANSWER_S)

    with concurrent.futures.ThreadPoolExecutor(1) as thread:
        try:
            identity = thread.submit(asyncio.run, ask()).result()
        except Exception:   # no answer in time, or bytes that are no Dask message
            return None
    return identity if isinstance(identity, dict) else None


def _what_answers(host: str, port: int) -> str:
    """What answers at ``host:port``, which is not Dask: a dashboard (naming its scheduler), a
    web server or something else."""
    no_proxy = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    url = f"http://{'[' + host + ']' if ':' in host else host}:{port}/json/identity.json"
    dashboard_port = (f"; {DASHBOARD_PORT} is the dashboard's usual port, the scheduler's is "
                      f"usually {SCHEDULER_PORT}" if port == DASHBOARD_PORT else "")
    try:
        with no_proxy.open(url, timeout=ANSWER_S) as response:
            body = response.read(1 << 16)
    except urllib.error.HTTPError:   # an HTTP answer all the same
        body = b""
    except OSError:
        return f"something other than a Dask scheduler answers there{dashboard_port}"
    try:
        identity = json.loads(body)
    except ValueError:
        identity = None
    if isinstance(identity, dict) and identity.get("type") == "Scheduler":
        return (f"this is the dashboard of the Dask scheduler at {identity.get('address')}; "
                "give that address")
    return f"a web server answers there, not a Dask scheduler{dashboard_port}"


def _web_address_hint(address: str) -> str:
    """What to give instead of the malformed ``address``: the scheduler's form, for a web
    address (the dashboard's ``http://``) with its host and the scheduler's usual port."""
    from distributed.comm.addressing import parse_address, parse_host_port

    scheme, location = parse_address(address)
    if scheme in ("http", "https"):
        try:
            host, port = parse_host_port(location.split("/")[0], SCHEDULER_PORT)
        except ValueError:
            host, port = "HOST", SCHEDULER_PORT
        dashboard = (f" ({DASHBOARD_PORT} is the dashboard's usual port)"
                     if port == DASHBOARD_PORT else "")
        port = SCHEDULER_PORT if port == DASHBOARD_PORT else port
        return (f"{scheme}:// is a web address, such as the dashboard's{dashboard}; give the "
                f"scheduler's, e.g. tcp://{host}:{port}")
    return f"give tcp://HOST:PORT (a scheduler's port is usually {SCHEDULER_PORT})"
