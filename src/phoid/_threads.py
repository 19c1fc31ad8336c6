"""One BLAS thread inside phoid's hot paths.

phoid's numerical work is many small matrix products (a few thousand elements at most). With
OpenBLAS's default of one thread per core, each such product wakes a thread pool whose workers
spin while they wait: on an idle machine that costs a little, on a busy one (another process on
every core — a test runner, a second phoid) it made an identification several times slower
(the measurement: docs/design-notes/history.md, "One BLAS thread"). The public entry points that do
the work therefore run with the BLAS pools limited to one thread, through threadpoolctl (the
library scikit-learn and joblib use for this), and restore the caller's setting on return.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

_controller: Any = None
#: len(sys.modules) when the controller was made: a module imported since may have loaded
#: another BLAS (scipy's own OpenBLAS, loaded with scipy.linalg, is not numpy's), which a
#: controller made before it would leave at its default threads
_modules_seen = -1


def _limit() -> Any:
    global _controller, _modules_seen
    if _controller is None or len(sys.modules) != _modules_seen:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
        _modules_seen = len(sys.modules)
    return _controller.limit(limits=1, user_api="blas")


def single_blas_thread(func: F) -> F:
    """Decorator: run ``func`` with every BLAS thread pool limited to one thread."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with _limit():
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
