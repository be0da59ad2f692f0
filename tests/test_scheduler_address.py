"""Issue 35: every bad ``iblbench run --scheduler`` is one line on stderr and exit 2 within 10 s,
naming the likely mistake where it can, and leaves no --out.  Before, a malformed address or
scheme was a traceback, a server that is not Dask made the client ask for 3 EiB, a closed port
took 15 s and the dashboard's port held the run for ever.

Each case meets a real server: a throwaway HTTP server, a socket whose accept queue is full (a
host that never answers the connect), and a real ``dask scheduler`` with its dashboard and a
``dask worker``, started once for the module.  The command line's cases time its start-up too;
the others call :func:`iblbench.run`, which shares the runner's path and costs no start-up."""
from __future__ import annotations

import contextlib
import http.server
import json
import os
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

import iblbench
from iblbench.harness.protocol.scheduler_address import check_scheduler

LIMIT_S = 10   # the bound on every bad address, start-up included


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def assert_refused_fast(tmp_path: Path, address: str, *needles: str) -> str:
    """``iblbench run --scheduler address``: exit 2 within LIMIT_S, one line holding every
    needle, no --out."""
    out = tmp_path / "out"
    start = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "iblbench.cli", "run", "--config", "quick", "--no-progress",
         "--scheduler", address, "--out", str(out)],
        capture_output=True, text=True, timeout=30, env=dict(os.environ, PYTHONWARNINGS="ignore"))
    elapsed = time.monotonic() - start
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert all(needle in lines[0] for needle in needles), lines[0]
    assert elapsed < LIMIT_S, f"{elapsed:.1f} s"
    assert not out.exists()
    return lines[0]


def assert_refused_in_process(tmp_path: Path, capfd, address: str, *needles: str) -> None:
    """:func:`iblbench.run` with ``scheduler=address``: an InputError within LIMIT_S holding
    every needle, nothing else on stderr, no ``out``."""
    start = time.monotonic()
    with pytest.raises(iblbench.InputError) as caught:
        iblbench.run(config="quick", scheduler=address, out=tmp_path / "out", progress=False)
    assert time.monotonic() - start < LIMIT_S
    assert all(needle in str(caught.value) for needle in needles), caught.value
    assert capfd.readouterr().err == ""
    assert not (tmp_path / "out").exists()


def test_a_malformed_address(tmp_path):
    assert_refused_fast(tmp_path, "notanaddress", "--scheduler notanaddress: not a Dask scheduler "
                        "address", "missing port", "tcp://HOST:PORT")


def test_a_web_scheme_names_the_schedulers_form(tmp_path, capfd):
    assert_refused_in_process(tmp_path, capfd, "http://127.0.0.1:8787",
                              "scheduler='http://127.0.0.1:8787': not a Dask scheduler address",
                              "unknown address scheme 'http'",
                              "8787 is the dashboard's usual port", "tcp://127.0.0.1:8786")


def test_a_host_that_never_answers_the_connect(tmp_path, capfd):
    """A listening socket whose accept queue is full drops new connections' SYNs: the connect
    waits as for an unreachable host (a real one, such as 10.255.255.1, may be answered by a
    proxy where the tests run)."""
    with socket.socket() as full:
        full.bind(("127.0.0.1", 0))
        full.listen(0)
        queued = socket.create_connection(full.getsockname(), timeout=5)   # fills the queue
        with queued:
            host, port = full.getsockname()
            assert_refused_in_process(tmp_path, capfd, f"tcp://{host}:{port}",
                                      "no Dask scheduler answers there (no answer in 3 s)")


def test_a_closed_port(tmp_path, capfd):
    """Refused for a few seconds (a scheduler started beside the run may not listen yet), not
    for the client's 10 s."""
    assert_refused_in_process(tmp_path, capfd, f"tcp://127.0.0.1:{_free_port()}",
                              "no Dask scheduler answers there (Connection refused for 5 s)")


class QuietHandler(http.server.BaseHTTPRequestHandler):
    """Answers every request with an HTTP error, and logs nothing (stderr is checked)."""

    def log_message(self, *args) -> None:
        pass


@contextlib.contextmanager
def http_server():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), QuietHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


def test_a_web_server_that_is_not_dask(tmp_path):
    """Its answer to Dask's handshake, read as a frame length, asked for 3.07 EiB."""
    with http_server() as port:
        assert_refused_fast(tmp_path, f"tcp://127.0.0.1:{port}",
                            "a web server answers there, not a Dask scheduler")


@pytest.fixture(scope="module")
def dask_cluster():
    """A real ``dask scheduler`` (its dashboard on a port of its own) and one ``dask worker``:
    (scheduler, dashboard, worker) addresses."""
    dask = Path(sys.executable).parent / "dask"
    scheduler, dashboard, worker = (_free_port() for _ in range(3))
    started = [subprocess.Popen(
        [dask, "scheduler", "--host", "127.0.0.1", "--port", str(scheduler),
         "--dashboard-address", f"127.0.0.1:{dashboard}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        started.append(subprocess.Popen(
            [dask, "worker", f"tcp://127.0.0.1:{scheduler}", "--no-nanny", "--nthreads", "1",
             "--host", "127.0.0.1", "--worker-port", str(worker), "--no-dashboard"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        _wait_for_worker(dashboard)
        yield (f"tcp://127.0.0.1:{scheduler}", f"tcp://127.0.0.1:{dashboard}",
               f"tcp://127.0.0.1:{worker}")
    finally:   # the worker first: without its scheduler it would wait to reconnect
        for process in reversed(started):
            process.terminate()
            process.wait(timeout=30)


def _wait_for_worker(dashboard: int, wait_s: float = 60) -> None:
    """Until the dashboard answers and its scheduler has the worker."""
    no_proxy = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    deadline = time.monotonic() + wait_s
    while True:
        with contextlib.suppress(OSError, ValueError):
            url = f"http://127.0.0.1:{dashboard}/json/identity.json"
            with no_proxy.open(url, timeout=2) as response:
                if json.loads(response.read())["workers"]:
                    return
        assert time.monotonic() < deadline, "the dask scheduler or worker did not start"
        time.sleep(0.2)


def test_the_dashboards_port_names_the_scheduler(tmp_path, dask_cluster):
    scheduler, dashboard, _ = dask_cluster
    assert_refused_fast(tmp_path, dashboard,
                        f"this is the dashboard of the Dask scheduler at {scheduler}")


def test_a_workers_address_names_its_scheduler(tmp_path, dask_cluster):
    scheduler, _, worker = dask_cluster
    assert_refused_fast(tmp_path, worker, "a Dask Worker answers there, not a scheduler; its "
                                          f"scheduler is at {scheduler}")


def test_a_real_scheduler_passes(dask_cluster):
    scheduler, _, _ = dask_cluster
    assert check_scheduler(scheduler) is None
    assert check_scheduler(scheduler.removeprefix("tcp://")) is None   # Dask's default scheme
