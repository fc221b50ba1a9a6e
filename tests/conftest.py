"""The suite's pytest hooks, and every shared fixture made visible to all tests by name.

The shared code lives in modules by concern, which tests import as top-level modules:
`ldraw_support` (the real data's location, `SHARED`, `LDRAW`, `MODELS`, `LIBRARY_ZIP`, `DESIGNS`,
the `needs_ldraw` marker, `part`/`at`, `BOX`; fixtures `real_reader`, `embedded_reader`, `write`,
`mini_library`, `isolated_cache`), `dataset_support` (`tiny_dataset_config`; fixture
`tiny_dataset`), `process_support` (`torchrun`, `children_of`, `alive`,
`assert_workers_end_with_killed_parent`) and `training_support` (`train_log`, `run_weights`,
`train_argv`, `interrupted_copy`, `assert_resumed_run_is_the_same`; fixture `tiny_model`).
Fixtures are found by name in this module's namespace, hence the imports below."""

from __future__ import annotations

import pytest

from dataset_support import tiny_dataset  # noqa: F401
from ldraw_support import LDRAW
from ldraw_support import embedded_reader, isolated_cache, mini_library, real_reader, write  # noqa: F401
from training_support import tiny_model  # noqa: F401


def pytest_collection_modifyitems(config, items):
    # Files with the most `slow` tests first (stable otherwise): `make test` hands whole files to
    # its workers in collection order, and a long file started last keeps one worker busy alone.
    slow: dict = {}
    for item in items:
        slow[item.path] = slow.get(item.path, 0) + bool(item.get_closest_marker("slow"))
    items.sort(key=lambda item: -slow[item.path])
    skip = pytest.mark.skipif(not (LDRAW / "parts").is_dir(), reason=f"the real LDraw subset is not at {LDRAW} "
                              "(CI has it; a user's clone may not; set BRICK_FACTORY_SHARED)")
    for item in items:
        if item.get_closest_marker("needs_ldraw"):
            item.add_marker(skip)
