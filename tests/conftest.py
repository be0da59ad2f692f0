"""Shared fixtures: one OpenCL context for the session, and a private reference cache."""
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
