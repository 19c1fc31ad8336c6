"""Lazy re-exports (PEP 562): a package's public names imported from their modules on first use.

``import phoid`` (and ``phoid --help``) should not pay for numpy, scipy and matplotlib, nor
``phoid identify`` for the forced and friction methods it does not run. A package that
re-exports names from its modules therefore lists them in a table, name → module, and takes its
module-level ``__getattr__`` and ``__dir__`` from :func:`lazy_exports`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, namespace: dict[str, Any], exports: Mapping[str, str]
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of a package that re-exports names lazily.

    Parameters
    ----------
    package : str
        The package's name (``__name__``), for the error message.
    namespace : dict
        The package's ``globals()``: an imported name is cached there, so that each is looked
        up once.
    exports : mapping of str to str
        Each public name → the module that defines it (absolute, e.g. ``"phoid.methods.pho"``).

    Returns
    -------
    (__getattr__, __dir__)
        ``__getattr__(name)`` imports ``name``'s module and returns the name (AttributeError,
        as for any module, for a name not in ``exports``); ``__dir__()`` lists the package's
        names with the public ones not yet imported.
    """

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
