"""Session-wide test settings: computed caches (RCWA η) go to a temporary folder, never to the
user's ~/.cache, and start empty."""

import pytest


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("METALENS_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield
