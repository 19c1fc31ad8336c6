"""The rig: phoid's PD controller in portable C, compiled with the machine's compiler and bound.

Public: :class:`Controller`, :class:`Event`, :class:`CompilerNotFoundError`,
:func:`build_library`, :func:`load_library`, :func:`find_compiler` (:mod:`phoid.rig.native`).
The C sources and their README are in ``phoid/rig/c``.

Around the controller: the line protocol ``PHOID-RIG 1`` (:mod:`phoid.rig.protocol`,
docs/rig-protocol.md), the virtual rig (:mod:`phoid.rig.virtual`, ``phoid virtual-rig``) and
the host driver (:mod:`phoid.rig.host`, ``phoid run``); import them from their modules.
"""

from typing import TYPE_CHECKING

from phoid._lazy import lazy_exports

if TYPE_CHECKING:  # the real imports, for type checkers; at run time see __getattr__
    from phoid.rig.native import (
        CompilerNotFoundError,
        Controller,
        Event,
        build_library,
        find_compiler,
        load_library,
    )

# imported on first use (PEP 562): `phoid --help` registers the rig's commands without loading
# ctypes and the binding
_EXPORTS = {name: "phoid.rig.native" for name in (
    "CompilerNotFoundError", "Controller", "Event", "build_library", "find_compiler",
    "load_library")}

__getattr__, __dir__ = lazy_exports(__name__, globals(), _EXPORTS)

__all__ = [
    "CompilerNotFoundError",
    "Controller",
    "Event",
    "build_library",
    "find_compiler",
    "load_library",
]
