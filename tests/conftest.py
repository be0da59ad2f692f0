"""Shared fixtures: one OpenCL context for the session, a private reference cache, and SIGINT
as a terminal leaves it."""
import signal
import warnings

import pytest

from iblbench.estimators.runtime.device import get_compute


def pytest_collection_modifyitems(items):
    """Slow modules first: under ``pytest -n 2 --dist loadfile`` (``make test``) the mutation
    catalogue then runs beside the rest instead of alone at the end.  The sort is stable, so
    the order within a module is kept."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory):
    """Keep the tests' cached references and device measurements out of the user's cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv("IBLBENCH_CACHE", str(tmp_path_factory.mktemp("iblbench-cache")))
    yield
    mp.undo()


@pytest.fixture(scope="session")
def compute():
    return get_compute()


@pytest.fixture(autouse=True)
def sigint_as_a_terminal_leaves_it(request):
    """A test that left SIGINT blocked or ignored in this worker would hand that on to every
    process a later test starts, and a Ctrl-C test's run would never see its Ctrl-C (three
    failed so in one clean-clone ``make test``): restore it after each test, and say which one
    left it."""
    yield
    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    handler = signal.getsignal(signal.SIGINT)
    if blocked or handler is not signal.default_int_handler:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        signal.signal(signal.SIGINT, signal.default_int_handler)
        warnings.warn(f"{request.node.nodeid} left SIGINT "
                      f"{'blocked' if blocked else f'handled by {handler!r}'}; restored")
